"""The Blender UI over the whole pipeline: panels, operators, and review of results."""
