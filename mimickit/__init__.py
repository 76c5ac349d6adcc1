"""MimicKit on MuJoCo: physics-based motion imitation (DeepMimic, AMP, ASE, ADD on PPO and AWR)."""

__version__ = "0.1.0"
