"""Making synthetic captures: dressing, cloth simulation, Blender rendering, ground truth, datasets."""
