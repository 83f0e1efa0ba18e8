"""Data: records, tables (CSV import/export), segmentation into blocks, signal helpers."""
