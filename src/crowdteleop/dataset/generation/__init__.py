"""MimicGen-style generation: new demonstrations from a few labelled ones, verified in simulation.

- `poses`: 4x4 pose maths (object frames, interpolation).
- `labels`: the subtask labels of a demo (stage, object each stage is relative to, hand and
  object poses) computed from its states, written as robomimic-side ``datagen_info`` and read
  back.
- `segments`: a labelled demo cut into its subtasks' segments.
- `attempt`: one new scene, segments chosen, transformed, stitched and executed; why it failed.
- `run`: `crowdteleop dataset generate` (workers, resuming, the episodes and the dataset).

docs/generation.md says how it works and what its flags mean.
"""
