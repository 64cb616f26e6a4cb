"""ONNX graph of a :class:`~controllers.export.window.WindowFeedforward` (the ``export`` extra).

Input ``r_window`` (float64, ``[batch, lag+1+lead]``: ``r[k-lag] .. r[k+lead]``, m), output
``u_ff`` (float64, ``[batch]``, N): the same computation as the C and the numpy form. The two
instants of the held average are stacked on the batch axis (``[2 batch, ...]``) after the
filter, computed once and averaged. Differences are taken before any scaling, in the product's
order (a scaled second difference of positions would lose digits), once per instant of the
window; the filter is then one MatMul per feature for both instants. The model's ``metadata_props`` carry ``ts``
(s), ``lag`` and ``lead`` (samples), the units and the model's description.
"""

from __future__ import annotations

import numpy as np

from clm_sim.errors import UserError
from clm_sim.rigid_body import rigid_body
from controllers.export.options import ExportOptions, safe_text
from controllers.activations import ACTIVATIONS
from controllers.export.window import WindowFeedforward

# The opset the graph is written in: 17, which most runtimes accept (every operator used here is
# defined there), and the IR version of that opset (onnx's table: opset 17 is
# IR 8), so that the file is consistent for older loaders.
OPSET = 17
IR_VERSION = 8


class _Graph:
    """Nodes and constants under construction, with fresh names."""

    def __init__(self):
        from onnx import helper, numpy_helper

        self.helper, self.numpy_helper = helper, numpy_helper
        self.nodes, self.inits, self.count = [], [], 0

    def name(self, base: str) -> str:
        self.count += 1
        return f"{base}_{self.count}"

    def const(self, value, base: str = "c") -> str:
        name = self.name(base)
        arr = np.asarray(value)
        if arr.dtype.kind == "f":
            arr = arr.astype(np.float64)
        self.inits.append(self.numpy_helper.from_array(arr, name))
        return name

    def op(self, op_type: str, *inputs: str, base: str | None = None, **attrs) -> str:
        out = self.name(base or op_type.lower())
        self.nodes.append(self.helper.make_node(op_type, list(inputs), [out], **attrs))
        return out

    def cols(self, x: str, start: int, end: int) -> str:
        """``x[:, start:end]`` (end may be negative)."""
        return self.op("Slice", x, self.const(np.array([start], np.int64)),
                       self.const(np.array([end], np.int64)),
                       self.const(np.array([1], np.int64)))


class _Node:
    """A node's output in the graph under construction: the ONNX namespace of a force law
    (:mod:`clm_sim.namespace`); arithmetic on it adds nodes (numbers become constants)."""

    __array_priority__ = 1000  # numpy scalars defer to these operators

    def __init__(self, g: _Graph, name: str):
        self.g, self.name = g, name

    def _in(self, x) -> str:
        return x.name if isinstance(x, _Node) else self.g.const(float(x))

    def _op(self, op: str, *inputs) -> "_Node":
        names = [self._in(x) for x in inputs]
        return _Node(self.g, self.g.op(op, *names))

    def __add__(self, o): return self._op("Add", self, o)
    def __radd__(self, o): return self._op("Add", o, self)
    def __sub__(self, o): return self._op("Sub", self, o)
    def __rsub__(self, o): return self._op("Sub", o, self)
    def __mul__(self, o): return self._op("Mul", self, o)
    def __rmul__(self, o): return self._op("Mul", o, self)
    def __truediv__(self, o): return self._op("Div", self, o)
    def __rtruediv__(self, o): return self._op("Div", o, self)
    def __gt__(self, o): return self._op("Greater", self, o)
    def __lt__(self, o): return self._op("Less", self, o)
    def __neg__(self): return self._op("Neg", self)
    def __pow__(self, o): return self._op("Pow", self, o)


class _OnnxNamespace:
    """The members of :mod:`clm_sim.namespace` as ONNX nodes (numbers fold in Python first, as
    ``2.0 * xp.pi``, and become one constant)."""

    pi = float(np.pi)
    sin = staticmethod(lambda x: x._op("Sin", x))
    exp = staticmethod(lambda x: x._op("Exp", x))
    abs = staticmethod(lambda x: x._op("Abs", x))
    sign = staticmethod(lambda x: x._op("Sign", x))
    tanh = staticmethod(lambda x: x._op("Tanh", x))
    relu = staticmethod(lambda x: x._op("Relu", x))
    # ONNX has no Log1p: Log(1 + x) loses x's relative digits where |x| << 1 but stays within
    # 1.1e-16 absolute, which is what a sum like softplus needs (TrackEnd's law)
    log1p = staticmethod(lambda x: x._op("Log", 1.0 + x))

    @staticmethod
    def const(x: float) -> float:
        return float(x)

    @staticmethod
    def full_like(x: _Node, value: float) -> _Node:
        return x * 0.0 + value  # the shape of x

    @staticmethod
    def where(condition: _Node, a, b) -> _Node:
        return condition._op("Where", condition, a, b)


class _Deferred(_Node):
    """A node made when it is first read (so that the constant beside it comes first)."""

    def __init__(self, g: _Graph, op: str, x: str):
        self.g, self._op_input, self._name = g, (op, x), None

    @property
    def name(self) -> str:
        if self._name is None:
            self._name = self.g.op(*self._op_input)
        return self._name


def _rename(g: _Graph, name: str, base: str) -> str:
    """The last node's output ``name`` renamed ``<base>_<n>`` (a readable graph)."""
    new = f"{base}_{name.rsplit('_', 1)[1]}"
    assert g.nodes[-1].output[0] == name
    g.nodes[-1].output[0] = new
    return new


def _effect(g: _Graph, e, y: str, v: str, base: str) -> str:
    """Force (N) of effect ``e`` (its law) as graph nodes of ``y`` (m), ``v`` (m/s), ``base``
    (N)."""
    try:
        out = e.law(_Node(g, y), _Node(g, v), _Node(g, base), _OnnxNamespace())
    except NotImplementedError:
        raise UserError(f"export: effect {e.type!r} has no ONNX form (no law of y, v, u)") \
            from None
    return out.name if isinstance(out, _Node) else _Node(g, y).__mul__(0.0).__add__(out).name


def _activation(g: _Graph, name: str, x: str) -> str:
    """The activation ``name`` (its law, :data:`~controllers.activations.ACTIVATIONS`) as
    graph nodes of ``x``. A sigmoid is ``1/(1 + e^-x)``, not the Sigmoid operator: ONNX
    Runtime's float64 Sigmoid is an approximation (1e-4 off, measured with 1.32), its Exp is
    exact to rounding. softplus uses Log(1 + e^x) (log1p below); gelu needs erf, which this
    namespace lacks."""
    try:
        return ACTIVATIONS[name].law(_Node(g, x), _OnnxNamespace()).name
    except AttributeError:
        raise UserError(f"export: activation {name!r} has no ONNX form here (use --to c)") \
            from None


def model(wf: WindowFeedforward, options: ExportOptions | None = None):
    """The ONNX ``ModelProto`` of ``wf`` at opset :data:`OPSET` (checked by ``onnx.checker``,
    full check), with the trace of ``options`` in its metadata."""
    import onnx
    from onnx import TensorProto, helper

    g = _Graph()
    width = wf.width
    c = wf.half + 1  # column of r[k]
    # The physical layer at both instants of the held average, stacked on the batch axis: rows
    # j = k, then j = k+1, each with r[j-1], r[j], r[j+1].
    # (Only where something reads them: a PGNN with a filter differences the whole window.)
    if wf.network is None or wf.half == 0:
        near = g.cols("r_window", c - 1, c + 3)
        pair = g.op("Concat", g.cols(near, 0, 3), g.cols(near, 1, 4), axis=0)
        xm, x0, xp = g.cols(pair, 0, 1), g.cols(pair, 1, 2), g.cols(pair, 2, 3)
        v = g.op("Div", g.op("Sub", xp, xm), g.const(2.0 * wf.ts), base="v")
        a = g.op("Div", g.op("Add", g.op("Sub", xp, g.op("Mul", g.const(2.0), x0)), xm),
                 g.const(wf.ts * wf.ts), base="a")
    th = wf.theta
    if wf.network is None:  # a LIP: theta and the effects on the raw differences
        p = rigid_body(th, _Node(g, a), _Node(g, v), _Deferred(g, "Sign", v), _Node(g, x0))
        p = _rename(g, p.name, "physical")
        base = p
        for e in wf.effects:
            p = g.op("Add", p, _effect(g, e, x0, v, base))
    else:
        net = wf.network
    if wf.network is not None and wf.half == 0:  # no feature filter: the raw features
        f = g.op("Concat", a, v, g.op("Sign", v), x0, axis=1, base="features")
    elif wf.network is not None:
        # The differences at every instant of the window (r[k-M] .. r[k+M+1]) in the product's
        # order, once; the filter's FIR at k and k+1 is one MatMul per feature with a [2M+2, 2]
        # kernel (its constant factors 1/ts^2 and 1/(2 ts) folded in: a rounding apart).
        right, mid, left = (g.cols("r_window", 2, width), g.cols("r_window", 1, width - 1),
                            g.cols("r_window", 0, width - 2))
        dv = g.op("Sub", right, left)
        da = g.op("Add", g.op("Sub", right, g.op("Mul", g.const(2.0), mid)), left)
        padded = np.concatenate([[0.0], wf.kernel, [0.0]])
        both = np.column_stack([padded[1:], padded[:-1]])  # weights at k, at k+1
        stacked = g.op("Concat", da, dv, g.op("Sign", dv), mid, axis=0)  # [4 batch, 2M+2]
        filtered = g.op("Mul", g.op("Reshape", g.op("MatMul", stacked, g.const(both, "kernel")),
                                    g.const(np.array([4, -1, 2], np.int64))),
                        g.const(np.array([1.0 / (wf.ts * wf.ts), 1.0 / (2.0 * wf.ts), 1.0, 1.0])
                                [:, None, None], "scale"))
        # [4 (a, v, sign v, y), batch, 2 (k, k+1)] -> [2 batch, 4]: rows k, then rows k+1
        f = g.op("Reshape", g.op("Transpose", filtered, perm=[2, 1, 0]),
                 g.const(np.array([-1, 4], np.int64)), base="features")
    if wf.network is not None:
        # A PGNN: theta on the same (filtered) features the network sees, as fitted.
        p = g.op("MatMul", f, g.const(wf.theta_vector()[:, None], "theta"), base="physical")
        h = g.op("Div", g.op("Sub", f, g.const(net.input_mean[None, :], "input_mean")),
                 g.const(net.input_std[None, :], "input_std"))
        for wl, bl in net.layers:
            h = _activation(g, net.activation,
                            g.op("Add", g.op("MatMul", h, g.const(wl.T.copy(), "weight")),
                                 g.const(bl[None, :], "bias")))
        out = g.op("Add", g.op("MatMul", h, g.const(net.out_w[:, None], "out_weight")),
                   g.const(np.array([[net.out_b]]), "out_bias"))
        p = g.op("Add", p, out, base="point_force")
    pair = g.op("Reshape", p, g.const(np.array([2, -1], np.int64)))
    first = g.op("Gather", pair, g.const(np.array(0, np.int64)), axis=0)
    second = g.op("Gather", pair, g.const(np.array(1, np.int64)), axis=0)
    g.nodes.append(helper.make_node("Mul", [g.const(0.5), g.op("Add", first, second)],
                                    ["u_ff"]))
    used = {name for node in g.nodes for name in node.input}
    opt = options or ExportOptions()
    graph = helper.make_graph(
        g.nodes, opt.prefix,
        [helper.make_tensor_value_info("r_window", TensorProto.DOUBLE, ["batch", width])],
        [helper.make_tensor_value_info("u_ff", TensorProto.DOUBLE, ["batch"])],
        initializer=[t for t in g.inits if t.name in used])  # no unused initializer
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="clm-sim export-ff", producer_version=opt.version,
                              doc_string=safe_text(wf.describe()))
    proto.ir_version = IR_VERSION
    meta = {"ts": repr(wf.ts), "lag": str(wf.lag), "lead": str(wf.lead),
            "units": "r_window: m (r[k-lag] .. r[k+lead]); u_ff: N, held over sample k; ts: s",
            "kind": wf.kind, "model": safe_text(wf.describe()),
            **{k: safe_text(v) for k, v in opt.trace().items()}}
    helper.set_model_props(proto, meta)
    onnx.checker.check_model(proto, full_check=True)
    return proto


def write(wf: WindowFeedforward, folder, options: ExportOptions | None = None) -> list:
    """Write ``<prefix>.onnx`` and its known-answer vectors ``<prefix>_kat.csv`` into
    ``folder``; returns the paths."""
    from pathlib import Path

    opt = options or ExportOptions()
    path = Path(folder) / f"{opt.prefix}.onnx"
    path.write_bytes(model(wf, opt).SerializeToString())
    from controllers.export import selftest

    return [path, *selftest.write(wf, folder, opt.prefix, c=False)]


# -- the plain-MLP form: the features in, the force at that instant out ----------------------
# The operators a runtime that accepts only plain MLPs runs (and Relu for a relu network).
MLP_OPS = {"tanh": "Tanh", "relu": "Relu"}


def mlp_model(wf: WindowFeedforward, options: ExportOptions | None = None):
    """The plain-MLP ONNX ``ModelProto`` of ``wf``: input ``features`` (float64, ``[batch, 4]``,
    ``[a, v, sign v, y]`` in SI units, filtered as the network and theta see them,
    :meth:`WindowFeedforward.features`), output ``force`` (float64, ``[batch, 1]``, N): the point
    force ``p = theta . f + f_NN(f)`` at that instant. Only MatMul, Add and the activation (Tanh;
    Relu for a relu network): the input scaling is folded into the first layer, theta is a linear
    branch in parallel, added at the end. The caller differences, filters and averages
    ``u_ff[k] = (p[k] + p[k+1])/2`` (docs/export.md). A LIP without effects is theta alone."""
    import onnx
    from onnx import TensorProto, helper

    if wf.effects:
        raise UserError("--onnx-form mlp: a LIP with effects is not a plain MLP (use the window "
                        "form)")
    net = wf.network
    if net is not None and net.activation not in MLP_OPS:
        raise UserError(f"--onnx-form mlp: activation {net.activation!r} is not a plain-MLP "
                        f"operator here ({', '.join(MLP_OPS)}); use the window form")
    g = _Graph()
    p = g.op("MatMul", "features", g.const(wf.theta_vector()[:, None], "theta"), base="physical")
    if net is not None:
        # (f - mean)/std then W: W/std on f, and b - W (mean/std) (a rounding apart)
        w0, b0 = net.layers[0]
        w_in = w0 / net.input_std[None, :]
        b_in = b0 - w_in @ net.input_mean
        layers = ((w_in, b_in),) + tuple(net.layers[1:])
        h = "features"
        for wl, bl in layers:
            h = g.op(MLP_OPS[net.activation],
                     g.op("Add", g.op("MatMul", h, g.const(wl.T.copy(), "weight")),
                          g.const(bl[None, :], "bias")))
        out = g.op("MatMul", h, g.const(net.out_w[:, None], "out_weight"))
        p = g.op("Add", p, out)
        g.nodes.append(helper.make_node("Add", [p, g.const(np.array([[net.out_b]]), "out_bias")],
                                        ["force"]))
    else:
        g.nodes[-1].output[0] = "force"
    opt = options or ExportOptions()
    graph = helper.make_graph(
        g.nodes, opt.prefix,
        [helper.make_tensor_value_info("features", TensorProto.DOUBLE, ["batch", 4])],
        [helper.make_tensor_value_info("force", TensorProto.DOUBLE, ["batch", 1])],
        initializer=g.inits)
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="clm-sim export-ff", producer_version=opt.version,
                              doc_string=safe_text(wf.describe()))
    proto.ir_version = IR_VERSION
    meta = {"ts": repr(wf.ts), "form": "mlp",
            "units": "features: [a m/s^2, v m/s, sign v, y m], filtered as the model's network "
                     "and theta see them; force: N at the instant of the features; "
                     "u_ff[k] = (force[k] + force[k+1])/2",
            "filter": _filter_text(wf), "kind": wf.kind, "model": safe_text(wf.describe()),
            **{k: safe_text(v) for k, v in opt.trace().items()}}
    helper.set_model_props(proto, meta)
    onnx.checker.check_model(proto, full_check=True)
    return proto


def _filter_text(wf: WindowFeedforward) -> str:
    """How the MLP form's features are filtered (for its metadata)."""
    if wf.network is None or not wf.filter.get("cutoff_hz"):
        return "none: central differences of the reference"
    return (f"central differences of the reference, then the zero-phase Butterworth of order "
            f"{wf.filter['order']} at {wf.filter['cutoff_hz']:g} Hz (scipy sosfiltfilt; as an "
            f"FIR, {len(wf.kernel)} taps)")


def mlp_write(wf: WindowFeedforward, folder, options: ExportOptions | None = None) -> list:
    """Write ``<prefix>.onnx`` (the plain-MLP form) and its known-answer vectors
    ``<prefix>_kat.csv`` (features and force at every instant of the vectors' motion)."""
    from pathlib import Path

    from controllers.export import selftest

    opt = options or ExportOptions()
    path = Path(folder) / f"{opt.prefix}.onnx"
    path.write_bytes(mlp_model(wf, opt).SerializeToString())
    kat = Path(folder) / f"{opt.prefix}_kat.csv"
    kat.write_text(selftest.features_kat_csv(wf))
    return [path, kat]
