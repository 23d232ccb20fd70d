"""TorchRL baselines: PPO, SAC and V-MPO, run by one module (baseline_run.py), each algorithm's
learner in its own module (ppo.py, sac.py, vmpo.py), on the pieces they share (env.py, nets.py,
harness.py)."""
