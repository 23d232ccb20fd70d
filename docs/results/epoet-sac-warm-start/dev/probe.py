"""The exploration probe of issue 36 (kept as the record of what README.md's probe rows ran;
not maintained). Loads the authors' actor into ePOET-SAC's learner at the workstation budget,
seed 1, without observation normalisation, collects `frames` frames of the actor on the root
environment's iteration-0 terrain, then runs `n` updates in three thirds and scores the actor
(3 episodes, Key.EVAL starts) after each:

    python probe.py adam 3e-4 300 4000      # actor-only updates, critics frozen
    python probe.py full 3e-4 300 4000      # the learner's SAC updates
    python probe.py warm2000 3e-4 300 4000  # 2000 critic-only updates first, then SAC updates
    python probe.py anchor1 3e-4 300 4000   # SAC updates with the actor anchored (weight 1)

(The anchor here scales by |Q(s, mu_0(s))|; epoet/rl/sac_loss.py uses |Q| of the sampled
action, which is cheaper.)"""
import sys, torch, numpy as np
from epoet.config import load
from epoet.epoet_sac.loop import EpoetSac
from epoet.epoet_sac.runner import warm_start_of
from epoet.poet.keys import Key
from epoet.poet.runner import layer_sizes
from epoet.rollout.evaluators import make_evaluator
from epoet.rl.env import terrain_env
from epoet.rl.nets import step_if_finite

mode, lr, n = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
cfg = load(["algo=epoet_sac", "budget=workstation", "workers.num=1", "seed=1", "budget.n_pairs=8", "algo.es.obs_norm_episodes=0"])
with make_evaluator(cfg.agent, cfg.terrain, 1, 8, layer_sizes(cfg)) as ev:
    loop = EpoetSac.from_config(cfg, ev, warm_start_of(cfg))
    pair = loop.pool.active[0]
    terrain = loop.service.terrain(pair.env, 0)
    seeds = loop.service.seeds(3, Key.EVAL, 0, 0)
    print("start", loop.exchange.actor_score(terrain, seeds))
    terrain_env(loop.sac_env).set_terrain(terrain)
    torch.manual_seed(0)
    data = loop.collect(int(sys.argv[4]) if len(sys.argv) > 4 else 4000, 123, explore=True)
    print("collected return", data["next", "episode_reward"][data["next","done"]].tolist())
    L = loop.learner
    L.add(data)
    opt = torch.optim.Adam(L.loss.policy_net.parameters(), lr=lr) if mode != "sgd" else torch.optim.SGD(L.loss.policy_net.parameters(), lr=lr)
    if mode.startswith("anchor"):
        import copy
        w = float(mode[6:])
        net = L.loss.policy_net
        anchor = copy.deepcopy(net).requires_grad_(False)
        orig = L.loss.losses
        def losses(obs, action, next_obs, reward, terminated):
            out = orig(obs, action, next_obs, reward, terminated)
            loc, _ = net(obs)
            with torch.no_grad():
                mu0 = torch.tanh(anchor(obs)[0])
                q = L.loss.critics(L.loss.critic_input(obs), mu0).min(0).values.abs().mean()
            out["loss_actor"] = out["loss_actor"] + w * q * (torch.tanh(loc) - mu0).square().sum(-1).mean()
            return out
        L.loss.losses = losses
        mode = "full"
    if mode.startswith("warm"):
        k = int(mode[4:])
        print("critic-only", L.gradient_steps(k, critics_only=True))
        mode = "full"
    if mode == "full":
        for k in range(3):
            print(L.gradient_steps(n // 3)); print("score", loop.exchange.actor_score(terrain, seeds), flush=True)
        raise SystemExit
    for i in range(n):
        s = L.buffer.sample(256)
        out = L.loss(s)
        if mode == "q":  # report only
            pass
        step_if_finite(opt, out["loss_actor"])
        if (i + 1) % (n // 3) == 0:
            print(i + 1, "loss_actor", float(out["loss_actor"]), "score", loop.exchange.actor_score(terrain, seeds), flush=True)
