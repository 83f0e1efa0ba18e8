"""Discovery: compare a hysteresis model with measurements, find where it fails and which
physical effect is missing (records, composite model, noise floor, breakdown, diagnosis).
Pure science: no HTTP, no store (the glue is service.usecases.discover)."""
