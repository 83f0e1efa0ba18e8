"""The science: data, models, effects, fitting, discovery and control. Knows no store, jobs or HTTP."""
