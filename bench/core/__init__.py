"""Foundations every layer uses: errors, the key=value config grammar, safe writes, JSON schemas, provenance, video,
the console tables are printed to."""
