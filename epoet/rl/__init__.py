"""TorchRL baselines: PPO, SAC and V-MPO, each trained by the loop in its own module (ppo.py,
sac.py, vmpo.py) on the pieces they share (env.py, nets.py, harness.py)."""
