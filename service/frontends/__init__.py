"""Front ends: the ``evcbench`` command line and the Python client."""
