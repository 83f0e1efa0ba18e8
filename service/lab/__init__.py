"""The lab: several benches on one store, and batch work over their datasets.

``address`` names a store so that another process (a Dask worker) can open its own; ``batch`` runs
identification, diagnosis and a bounded discovery loop over many datasets, in process or on a Dask
cluster, one task per dataset and axis; ``emulated`` records emulated sweeps into a store (the
benchmark's and the tests' datasets).
"""

from service.lab.address import StoreAddress, open_store

__all__ = ["StoreAddress", "open_store"]
