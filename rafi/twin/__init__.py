"""The spindle's digital twin and every generator of synthetic data (one place)."""
