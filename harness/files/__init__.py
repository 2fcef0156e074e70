"""Files: input parsing (strict YAML), tables (CSV/Parquet), output folders that never replace a user's files, caches."""
