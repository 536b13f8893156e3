"""C code for one model: CasADi-generated functions plus the ``mt_model`` descriptor of the runtime contract.

``model_casadi.c`` holds the CasADi code generation of the functions of
:meth:`fmus.symbolic.SymbolicModel.functions`; ``model.c`` holds ``const mt_model MT_MODEL``
with the variable table of :mod:`fmus.layout` (names, start values the binary uses by default,
bounds, nominals). Start values are compiled in, so defaults always equal the XML start values.
"""
from __future__ import annotations

import hashlib
import math
import uuid
from pathlib import Path

import casadi as ca

from motiontwin.fmus.layout import Layout
from motiontwin.fmus.symbolic import SymbolicModel

CASADI_FILE = "model_casadi.c"
MODEL_FILE = "model.c"
_CONTRACT = ("x0", "ode", "out", "jac", "dfdt", "sample", "ode_jac", "sample_matrix")


def generate(model: SymbolicModel, table: Layout, identifier: str, out_dir: Path, salt: bytes = b"") -> str:
    """Write ``model_casadi.c`` and ``model.c`` into ``out_dir``; return the token.

    The token (guid / instantiationToken) is a hash of the generated code and ``salt`` (the runtime
    sources and FMI version), so the same model built the same way always gets the same token.
    """
    functions = runtime_functions(model.functions())
    gen = ca.CodeGenerator(CASADI_FILE, {"with_header": False, "prefix": "mt_", "casadi_real": "double",
                                         "casadi_int": "long long", "verbose": False})
    generated = {}
    for key, fn in functions.items():  # CasADi's "prefix" option only renames its internal helpers
        args = fn.sx_in()
        generated[key] = ca.Function(f"mt_{fn.name()}", args, fn.call(args), fn.name_in(), fn.name_out(),
                                     {"cse": True})
    if "ode_jac" in generated and "jac" in generated:
        generated["jac"] = _full_jacobian(functions, generated["ode_jac"])
    for fn in generated.values():
        gen.add(fn)
    gen.generate(str(out_dir) + "/")
    digest = hashlib.sha256(salt + (out_dir / CASADI_FILE).read_bytes())
    digest.update(_descriptor(model, functions, table, identifier, "").encode())
    token = "{" + str(uuid.UUID(bytes=digest.digest()[:16], version=4)) + "}"
    (out_dir / MODEL_FILE).write_text(_descriptor(model, functions, table, identifier, token))
    return token


def runtime_functions(functions: dict[str, ca.Function]) -> dict[str, ca.Function]:
    """The contract functions plus the two the runtime uses on its hot paths (see mt_model.h).

    ``ode_jac`` evaluates dx and the square state Jacobian d(dx)/dx together (the solver needs both at
    every accepted point; one function shares their common subexpressions, and the full ``jac`` also
    differentiates the outputs and with respect to the inputs). ``dfdt`` is dropped when dx does not
    depend on time (the runtime then uses zero). ``sample_matrix`` maps the parameters to the matrix S
    with [z_next; yd] = S [z; u], so that a sample is a small matrix-vector product instead of
    re-evaluating a discretisation that is symbolic in the parameters; it exists only when the sampled
    part is linear without offset in z and u.
    """
    out = dict(functions)
    ode = functions.get("ode")
    if ode is not None:
        t, x, u, p = ode.sx_in()
        dx = ode.call([t, x, u, p])[0]
        out["ode_jac"] = ca.Function("ode_jac", [t, x, u, p], [dx, ca.densify(ca.jacobian(dx, x))])
        if not ca.depends_on(dx, t):
            out.pop("dfdt", None)
    sample = functions.get("sample")
    if sample is not None:
        z, u, p = sample.sx_in()
        value = ca.vertcat(*sample.call([z, u, p]))
        known = ca.vertcat(z, u)
        matrix = ca.jacobian(value, known)
        offset = ca.substitute(value, known, ca.SX.zeros(known.numel()))
        if not ca.depends_on(matrix, known) and offset.is_zero():
            out["sample_matrix"] = ca.Function("sample_matrix", [p], [ca.densify(matrix)])
    return out


def _full_jacobian(functions: dict[str, ca.Function], ode_jac: ca.Function) -> ca.Function:
    """``jac`` (d[dx; y]/d[x; u]) that calls the generated ``ode_jac`` for its d(dx)/dx block.

    The code generator emits a called function once, so the state Jacobian, the largest block, is not
    compiled twice (for the 6-DOF hexapod it is most of the generated code).
    """
    t, x, u, p = functions["ode"].sx_in()
    dx = functions["ode"].call([t, x, u, p])[0]
    y = functions["out"].call([t, x, u, p])[0]
    rest = ca.Function("mt_jacobian_rest", [t, x, u, p],
                       [ca.densify(ca.jacobian(dx, u)), ca.densify(ca.jacobian(y, x)), ca.densify(ca.jacobian(y, u))],
                       {"cse": True})
    args = [ca.MX.sym(name, sx.shape) for name, sx in zip(("t", "x", "u", "p"), (t, x, u, p))]
    jxx = ode_jac.call(args)[1]
    jxu, jyx, jyu = rest.call(args)
    full = ca.vertcat(ca.horzcat(jxx, jxu), ca.horzcat(jyx, jyu))
    return ca.Function("mt_jacobian", args, [ca.densify(full)], functions["jac"].name_in(), functions["jac"].name_out())


def _c_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ") + '"'


def c_double(x: float | None) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "NAN"
    if math.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    return repr(float(x))


def _c_array(ctype: str, name: str, items: list[str]) -> str:
    body = ",\n    ".join(items) if items else "0"
    return f"static const {ctype} {name}[] = {{\n    {body}\n}};\n"


def _descriptor(model: SymbolicModel, functions: dict[str, ca.Function], table: Layout, identifier: str,
                token: str) -> str:
    s = table.sizes
    v = table.variables
    decls = []
    fields = []
    for key in _CONTRACT:
        fn = functions.get(key)
        if fn is None:
            fields.append(f"    .{key} = {{0, 0}},")
            continue
        name = f"mt_{fn.name()}"
        decls.append(f"int {name}(const double **arg, double **res, mt_int *iw, double *w, int mem);\n"
                     f"int {name}_work(mt_int *sz_arg, mt_int *sz_res, mt_int *sz_iw, mt_int *sz_w);")
        fields.append(f"    .{key} = {{{name}, {name}_work}},")
    start = [c_double(x.start) for x in v]
    return (
        "/* Generated by motiontwin (fmus/codegen.py) for " + model.name + ". Do not edit. */\n"
        "#include <math.h>\n#include \"mt_model.h\"\n\n"
        + "\n".join(decls) + "\n\n"
        + _c_array("char *const", "names", [_c_string(x.name) for x in v])
        + _c_array("double", "start", start)
        + _c_array("double", "min_", [c_double(x.min) for x in v])
        + _c_array("double", "max_", [c_double(x.max) for x in v])
        + _c_array("double", "nominal", [c_double(x.nominal or 1.0) for x in v])
        + "\nconst mt_model MT_MODEL = {\n"
        f"    .identifier = {_c_string(identifier)},\n"
        f"    .token = {_c_string(token)},\n"
        f"    .nx = {s['x']}, .nu = {s['u']}, .ny = {s['y']}, .nyd = {s['yd']}, .nz = {s['z']}, .np = {s['p']},\n"
        f"    .ts_index = {model.ts_index},\n"
        f"    .nvr = {len(v)},\n"
        "    .names = names, .start = start, .min = min_, .max = max_, .nominal = nominal,\n"
        + "\n".join(fields) + "\n};\n"
    )
