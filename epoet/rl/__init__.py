"""TorchRL baselines: PPO and SAC (TorchRL's own losses) and V-MPO (:mod:`epoet.rl.vmpo`)."""
