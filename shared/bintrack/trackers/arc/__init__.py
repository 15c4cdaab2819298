"""Single-target trackers at the peer agents (papers 000, 001): the algebra of arcs, the arc
tracker, the sector tracker, the four baselines of paper 001 §5.3.1, the analytic bounds of §4,
velocity (§3.2.3) and trajectory fitting (§3.2.4)."""
