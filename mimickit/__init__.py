"""MimicKit on MuJoCo: physics-based motion imitation (DeepMimic, AMP, ASE, ADD on PPO and AWR)."""

__version__ = "0.1.0"

# No OpenMP wait policy is set here. Torch's idle OpenMP workers spin a little (libgomp: ~300k spins)
# before they sleep. An update's ops follow one another closely, and the spin keeps the workers ready
# for the next op. OMP_WAIT_POLICY=PASSIVE, which this package once set, put them to sleep after every
# op: each op then paid a wake-up. On a loaded machine the update took 50% of a training iteration
# instead of 29% (`mimickit bench --train`, GOMP_SPINCOUNT=0 vs the default); on a quiet one the two
# are within noise. The rollout runs torch on one thread (`util.threads`), so no worker spins on a core
# that MuJoCo needs.
