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
             "parameters": {"m": 95.0},    optional start values (default: the Modelica values; the other
                                           parameters entering the force linearly start from inverse dynamics)
             "free": ["m", "d"],           optional: the parameters the nominal refit moves (default: every
                                           non-zero one; the others keep their values)
             "pole_pitch": 0.032},         optional: the motor's magnet pole pitch [m] (enables cogging)
   "controller": {"kind": "discrete_state_space", "Ts": 0.0005, "inputs": ["r", "q"], "outputs": ["u"],
                  "A": [[...]], "B": [[...]], "C": [[...]], "D": [[...]]}
              or {"kind": "MotionTwin.Controllers.RobustJointController", "parameters": {"Kp": 2e5, ...}}
              or {"kind": "unknown"} (optional "Ts", "bandwidth_hz"), the same as no "controller" field,
   "recordings": {"train": "train.csv", "validation": "validation.csv"}}

train.csv, validation.csv: columns time [s], r [m], u [N], q [m], optional u_ext [N], sampled at the
controller's instants (step Ts, or a whole number N of Ts: a faster controller is then simulated at its own
period, N updates per sample); closed loop: u = controller output + u_ext is the force the plant got.
Every file named in experiment.json must resolve (symbolic links followed) inside the bundle folder.
The recordings may start while the loop is moving.

Unknown controller (no "controller" field, or kind "unknown"; one axis): the recordings need only time, u, q
(r and u_ext are not used: u already holds u_ext). Method: a prediction-error predictor, the closed loop the
diagnosis runs with a PD observer L (damping 0.7; its mass the refitted plant's, its bandwidth fitted with the
plant by prediction error up to 1/(100 Ts), unless "mass" or "bandwidth_hz" give them) in place of the
controller, reference r = q and disturbance u_ext = u: the model gets u + L(q - q_model), so a double
integrator does not drift; every fit estimates the predictor's start (the plant's position and velocity).
Its output residual is the prediction
error, its force residual the observer's correction. Validation RMS: the predictor's free run (lower than a
simulation error; not comparable with a known controller's). diagnosis.json "controller" states the observer.

Several axes (a gantry, a coupled mechanism in actuator coordinates): plant.axes instead of input/output,
one entry per axis, named by its output; "parameters" and "free" stay plant-wide:
  "plant": {"modelica": "plant.mo", "class": "Gantry",
            "axes": [{"input": "u1", "output": "q1"},                        per axis optional: "position",
                     {"input": "u2", "output": "q2", "pole_pitch": 0.032}],  "velocity", "pole_pitch"
            "free": ["m1", "m2", "d"]}
  "controller": {"kind": "per_axis", "axes": [CONTROLLER_1, CONTROLLER_2]}   one single-axis controller per
                                           axis (either form above, inputs ["r", "q"], the same Ts), or one
                {"kind": "discrete_state_space", "Ts": ..., "inputs": ["r_q1", "r_q2", "q1", "q2"],
                 "outputs": ["u1", "u2"], "A": ..., "B": ..., "C": ..., "D": ...}   multivariable
  train.csv, validation.csv: columns time [s] and per axis r_<output> [m], <input> [N], <output> [m],
  optional u_ext_<input> [N], e.g. time,r_q1,u1,q1,r_q2,u2,q2.
Each effect found names its axis; the validation RMS is given per axis.
"""
BUNDLE_FORMAT += limits_help().replace("; ", ";\n  ") + "\n"
