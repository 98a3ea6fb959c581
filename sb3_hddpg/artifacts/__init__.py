"""Everything on disk: atomic writes, limits and allow-lists for files from elsewhere, safe model loading."""
