"""Does a path start's action history matter? Plays a checkpoint from starts on the expert's path
with the history empty and filled with the expert's last actions.

    python docs/run_data/history_starts.py RUN 40,80 30   # RUN: a two-room run folder
"""
import sys

from dqn_mine.agent.policy import AgentPolicy
from dqn_mine.env import MineRescueEnv
from dqn_mine.env.expert import solve
from dqn_mine.system.backward import start_budget

run, to_gos, n = sys.argv[1], [int(x) for x in sys.argv[2].split(",")], int(sys.argv[3])
agent = AgentPolicy.from_checkpoint(run + "/checkpoint.pt", epsilon=0.01, seed=0)
env = MineRescueEnv(task="two-room")
limit = env.max_episode_steps
h = agent.history_len
for to_go in to_gos:
    wins = {"empty": 0, "expert": 0}
    for seed in range(5000, 5000 + n):
        sol = solve(env, seed, limit)
        if to_go >= len(sol):
            continue
        for mode in wins:
            env.max_episode_steps = start_budget(to_go, limit)
            env.reset(seed=seed)
            obs, info = env.fast_forward(sol[:len(sol) - to_go])
            agent.core.begin(0, obs, bool(info["carrying"]))    # an empty history
            past = sol[:len(sol) - to_go][-h:]
            if mode == "expert" and past:
                agent.core.histories[0, -len(past):] = past
            done, ret = False, 0.0
            a = int(agent.core.act()[0][0])
            while not done:
                obs, r, term, trunc, info = env.step(a)
                ret += r
                done = term or trunc
                if not done:
                    agent.core.observe(0, a, obs, bool(info["carrying"]))
                    a = int(agent.core.act()[0][0])
            wins[mode] += ret > 0
    print(f"to_go {to_go}: successes of {n}: {wins}", flush=True)
