"""The sensor model along a recorded motion, and the effects interface (the discrepancy workflow's)."""
