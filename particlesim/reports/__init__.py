"""Reports that the command line writes (tables, CSV/JSON, plots)."""
