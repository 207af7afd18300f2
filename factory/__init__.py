"""Making synthetic captures: dressing, cloth simulation on moving bodies, Blender scenes and rendering,
ground truth, dataset layout and sharding.

The flat API: the settings and the entry points a script calls, each a name of this package::

    import factory

    sim = factory.SimulationConfig(garment="shirt", motion="walk", frames=240)
    sequence = factory.simulate_garment(sim, "out/sim")               # sequence.npz (`factory.simulate`)
    manifest = factory.build_dataset(factory.DatasetConfig("shirt", ("walk", "run")), "out/ds")
    folder = factory.capture_sequence("shirt", "walk", "out/cap", frames=12, cameras=8)
    parts = factory.build_recipe("modules_reader", "out/datasets/modules_reader")
    factory.merge_datasets("out/all", [factory.MergeSource("out/ds"), factory.MergeSource("out/more", True)])

Settings: `SimulationConfig`, `ClothParams`, `DressingParams`, `HealthLimits`, `DatasetConfig`,
`RenderSettings`, `DataRecipe`.  Entry points: `simulate_garment` (`factory.simulate.simulate`),
`dress_garment` (`factory.dressing.dress`), `build_dataset` (`factory.build.build`), `capture_sequence`
(`factory.capture.capture`), `build_recipe` (`factory.recipe.build_recipe`), `merge_datasets`
(`factory.merge.merge`, with `MergeSource`), `render_job` (`factory.render.render_job`: Blender).
Errors a run raises on its own terms: `SimulationError`, `DressingError`.  The entry points' names
are not those of the modules that hold them, so `factory.simulate` is always the module.

The CLIs, thin shells over these: ``python -m factory.simulate``, ``python -m factory.dressing``,
``python -m factory.dataset build | capture | merge | preview``, ``blender -b -P factory/render.py``.

A name is imported when first used (PEP 562), so ``import factory`` stays cheap: bpy only comes with
rendering, and nothing of the factory imports torch.
"""

from __future__ import annotations

from assets.lazy import lazy_api

#: name -> (module, attribute) of the flat API
_API = {
    "SimulationConfig": ("factory.simulate", "SimulationConfig"),
    "HealthLimits": ("factory.simulate", "HealthLimits"),
    "SimulationError": ("factory.simulate", "SimulationError"),
    "simulate_garment": ("factory.simulate", "simulate"),
    "ClothParams": ("factory.cloth", "ClothParams"),
    "DressingParams": ("factory.dressing", "DressingParams"),
    "DressingError": ("factory.dressing", "DressingError"),
    "dress_garment": ("factory.dressing", "dress"),
    "DatasetConfig": ("factory.plan", "DatasetConfig"),
    "RenderSettings": ("factory.plan", "RenderSettings"),
    "build_dataset": ("factory.build", "build"),
    "capture_sequence": ("factory.capture", "capture"),
    "DataRecipe": ("factory.recipe", "DataRecipe"),
    "build_recipe": ("factory.recipe", "build_recipe"),
    "merge_datasets": ("factory.merge", "merge"),
    "MergeSource": ("factory.merge", "Source"),
    "render_job": ("factory.render", "render_job"),
}

__all__ = sorted(_API)


__getattr__, __dir__ = lazy_api(__name__, _API)
