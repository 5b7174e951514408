"""`crowdteleop tasks`: the catalogue listed, and each task's fast path checked against plain
robosuite (step and render time, picture fidelity, per-step drift) before a campaign uses it."""
