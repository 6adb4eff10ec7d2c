"""swat_jax's bodies for other libraries' trainers.

- playground.py: one body as a MuJoCo Playground environment (``MjxEnv``), which Brax's PPO and SAC train
  on through Playground's wrapper (needs the ``playground`` extra).
"""
