"""The diagnosis bundle format as text: a module without heavy imports, so that ``motiontwin --help``
stays fast (the CLI prints it in ``motiontwin diagnose --help``)."""
from motiontwin.fmus.limits import limits_help

#: The bundle format, as ``motiontwin diagnose --help`` prints it.
BUNDLE_FORMAT = """\
A bundle is a folder with experiment.json, train.csv and validation.csv.

experiment.json:
  {"plant": {"modelica": "plant.mo",       Modelica file inside the bundle (elsewhere: --allow-outside-paths)
             "class": "LinearAxis",        class with a force input and a position output (a state, an
                                           alias of one or an affine expression: gear ratio, sensor offset)
             "input": "u", "output": "q",  optional (these defaults); other inputs are held at their start
             "position": "x",              optional: the position and velocity states (default: found from
             "velocity": "v",              the output's derivative chain, der(position) = velocity)
             "parameters": {"m": 95.0}},   optional start values (default: the Modelica values; the other
                                           parameters entering the force linearly start from inverse dynamics)
   "controller": {"kind": "discrete_state_space", "Ts": 0.0005, "inputs": ["r", "q"], "outputs": ["u"],
                  "A": [[...]], "B": [[...]], "C": [[...]], "D": [[...]]}
              or {"kind": "MotionTwin.Controllers.RobustJointController", "parameters": {"Kp": 2e5, ...}},
   "recordings": {"train": "train.csv", "validation": "validation.csv"}}

train.csv, validation.csv: columns time [s], r [m], u [N], q [m], optional u_ext [N], sampled at the
controller's instants (step Ts); closed loop: u = controller output + u_ext is the force the plant got.
Every file named in experiment.json must resolve (symbolic links followed) inside the bundle folder.
The recordings may start while the loop is moving.

"""
BUNDLE_FORMAT += limits_help().replace("; ", ";\n  ") + "\n"
