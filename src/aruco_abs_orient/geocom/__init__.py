"""geocom."""
