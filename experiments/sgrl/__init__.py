"""SGRL's own trainer (the 3D oracle) beside swat_jax: its runs (``runs``), the stand-in for wandb that records
what its logger sends (``recorder/wandb``) and its curves (``curves``)."""
