"""Experiments: running tasks × methods × seeds and the statistics reported on them."""
