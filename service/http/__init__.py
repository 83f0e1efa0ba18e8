"""HTTP routers. They translate requests to calls on the bench, store and science; no science here."""
