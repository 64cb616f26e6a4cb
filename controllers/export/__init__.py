"""Export an identified feedforward to a real-time target: the window form
(:mod:`controllers.export.window`), C99 source (:mod:`controllers.export.c_source`) and an ONNX
graph (:mod:`controllers.export.onnx_graph`, needs the ``export`` extra)."""

from controllers.export.window import WindowFeedforward, from_lip, from_pgnn

__all__ = ["WindowFeedforward", "from_lip", "from_pgnn"]
