"""How a recording was made, typed: below every package that makes or reads one.

- `crowdteleop.provenance.controllers`: robosuite's controller configurations for our two
  action modes. The one place the OSC's scales and gains are written: live control
  (`control.osc`), the robosuite backend and the dataset tools (`actions_abs`, replay in plain
  robosuite) all read them from here.
- `crowdteleop.provenance.env_args`: robomimic's ``env_args`` (and robosuite's ``env_info``
  derived from it), built from a simulation's settings and parsed back from a file.

Pure pydantic on top of `errors`, `vocab` and `tasks`: importing it loads no simulator, so the
coordinator, the recorder and the network bot may all read it.
"""
