"""clm-sim: a 10 kHz simulation of a coreless linear motor and its feedforward identification.

The public API, one import away (see the README's "Python API")::

    from clm_sim import Testbed

``clm_sim`` itself holds the physics and the data (plant, effects, loop, records). The names below
that live in the layers above it (controllers, experiments) are resolved lazily on first use
(PEP 562), so ``import clm_sim.plant`` never loads the controllers, torch or matplotlib, and this
package's modules never import a layer above them.
"""

from clm_sim.lazy import lazy_exports

__version__ = "0.8.0"
"""The version of clm-sim (``MAJOR.MINOR.PATCH``), as ``clm-sim --version`` prints it and as
``table.json`` records it beside each result.

Examples
--------
>>> import clm_sim
>>> len(clm_sim.__version__.split("."))
3
"""

# public name -> module that defines it
_EXPORTS = {
    "Testbed": "experiments.testbed",
    "ExperimentConfig": "experiments.config",
    "FeedforwardSpec": "experiments.config",
    "Training": "experiments.config",
    "PGNNSettings": "controllers.pgnn_settings",
    "load_config": "experiments.config",
    "Plant": "clm_sim.plant",
    "EFFECTS": "clm_sim.effects",
    "Run": "clm_sim.run",
    "load_record": "clm_sim.records.read",
    "simulate": "clm_sim.loop",
    "Dither": "clm_sim.loop",
    "PointToPoint": "clm_sim.reference",
    "FeatureMap": "clm_sim.features",
    "UserError": "clm_sim.errors",
    "NotFittedError": "clm_sim.errors",
    "PIDDesign": "controllers.pid",
    "design_pid": "controllers.pid",
    "LIPFeedforward": "controllers.lip",
    "PGNNFeedforward": "controllers.pgnn",
    "diagnose": "experiments.diagnosis",
    "load_model": "experiments.model_files",
    "DiagnosisSettings": "experiments.diagnosis",
}

__all__ = ["__version__", *_EXPORTS]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
