"""Reference implementations that check M3C's core and serve as baselines in bench/; the pipeline never imports
them. torch_objective: one world-optimizer stage's objective written again in torch."""
