"""What the TorchRL baselines share: their run (baseline_run.py: collect, learn, evaluate), their
settings' common parts (config.py), env (env.py), networks (nets.py), on-policy update
(on_policy.py) and policy files. Each algorithm lives in its own package: epoet/ppo/,
epoet/sac/, epoet/vmpo/."""
