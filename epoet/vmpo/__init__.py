"""V-MPO (Song et al. 2019): its settings and record (config.py), its loss (loss.py, on
loss_parts.py) and its runner (train.py)."""
