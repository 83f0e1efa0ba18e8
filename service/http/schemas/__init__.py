"""Request and response models of the REST API, one module per resource (the routes live in
service/http/*.py). Units live in field names: _v volts at the actuator, _um micrometres, _hz, _s.

Response models name every field a route returns, with the values it returns today; where a
payload is open-ended (the bench's description, a diagnosis, a job's result) the model names the
known fields and lets the rest through (``extra="allow"``). Routes whose answers leave some of
the named fields out use ``response_model_exclude_unset``, so an absent field stays absent.
"""
