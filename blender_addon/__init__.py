"""The Blender UI over the whole pipeline: panels, operators, and review of results.

A "Cloth Capture" tab in the 3D view's sidebar (`panels`) whose operators (`operators`) run the
project's command-line tools in a background process with the project's Python (`jobs`, `commands`)
and import their results into the scene (`results`, `scene`); settings live on the scene
(`settings`).  Installable as a Blender extension (``blender_manifest.toml``; Blender 4.2+) and as a
legacy add-on (`bl_info`); ``python -m blender_addon.package`` builds the zip that serves both.

Importing this package costs nothing: bpy is imported by `register`, numpy and the project's packages
when an operator first needs them (so the add-on registers in a Blender whose preferences do not
name the project yet).
"""

bl_info = {
    "name": "Cloth Capture",
    "author": "clothcapture contributors",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "3D View > Sidebar > Cloth Capture",
    "description": "4D cloth capture with a two-level pattern: pattern, body and motion, garment simulation, "
                   "synthetic renders, reconstruction review",
    "category": "Import-Export",
}

_MODULES = ("library", "settings", "operators", "panels")


def register() -> None:
    from importlib import import_module

    done = []
    try:
        for name in _MODULES:
            module = import_module(f"{__name__}.{name}")
            module.register()
            done.append(module)
    except Exception:  # leave nothing half-registered behind
        for module in reversed(done):
            module.unregister()
        raise


def unregister() -> None:
    from importlib import import_module

    import_module(f"{__name__}.jobs").shutdown()
    for name in reversed(_MODULES):
        import_module(f"{__name__}.{name}").unregister()
