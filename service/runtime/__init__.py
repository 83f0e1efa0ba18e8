"""Runtime: the app, the job manager, start-up recovery, shut-down, settings and the bench engine process."""
