"""The lab: several benches on one store, and batch work over their datasets.

``address`` names a store so that another process (a Dask worker) can open its own; ``batch`` runs
identification, diagnosis and a bounded discovery loop over many datasets, in process or on a Dask
cluster, one task per dataset and axis; ``emulated`` runs emulated sweeps without a service, as
Records (the reports', benchmarks' and tests' data) or recorded into a store (the batch benchmark's).
"""

from service.lab.address import StoreAddress, open_store

__all__ = ["StoreAddress", "open_store"]
