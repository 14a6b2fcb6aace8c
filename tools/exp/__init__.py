"""The paper's experiments as runs (tools/experiments.py is the command): one module per experiment
with NAME, TITLE, PAPER (its claim), PRESETS (full and fast parameters), runs(), summarise(),
figure() and table()."""

from tools.exp import bigmaps, chicago, cost, mavlink, obstacles, swarm, transfer

EXPERIMENTS = {m.NAME: m for m in (transfer, obstacles, bigmaps, swarm, chicago, cost, mavlink)}
