"""Wireless InSite readers, one module per file family: p2m, txrx, setup, city (and .ter)."""
