"""Data: direction sampling, measured and synthetic materials, sample sets."""
