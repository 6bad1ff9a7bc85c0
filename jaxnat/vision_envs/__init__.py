"""Pure-JAX navigation tasks over image datasets: `classify.py`, `localize.py`."""
