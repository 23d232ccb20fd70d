"""PPO (paper Table 2): its settings and record (config.py) and its learner's loss (train.py)."""
