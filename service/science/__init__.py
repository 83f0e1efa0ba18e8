"""The science: data, models, effects, fitting, discovery and control. Knows no store, jobs or HTTP.

Importing it limits BLAS to one thread (service.science.determinism): its figures must not depend
on the machine's load."""
from service.science.determinism import limit_blas_threads

limit_blas_threads()
