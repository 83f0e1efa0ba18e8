"""Use cases: what a user asks for (acquire, import, identify, compare, discover, track), tying the
science to the store and the jobs. The only layer that knows both."""
