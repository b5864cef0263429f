"""Safe file handling shared by every command: atomic writes, bounded reads, trust checks."""
