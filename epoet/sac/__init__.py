"""SAC (paper Table 3): its settings and record (config.py), its loss (loss.py), the learner
(learner.py) that `algo=sac` and ePOET-SAC share, and `algo=sac`'s runner (train.py)."""
