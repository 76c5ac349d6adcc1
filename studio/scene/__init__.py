"""The 3D scene: the one thread that owns it, what it plays (clips, rollouts, A/B pairs) and how
it is drawn in viser."""
