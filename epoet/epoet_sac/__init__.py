"""ePOET-SAC: the ePOET loop with a SAC learner beside the pool (loop.py), the bridge between
the two policy shapes (bridge.py) and its settings (config.py)."""
