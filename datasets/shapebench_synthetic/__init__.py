"""The built-in synthetic benchmark: procedurally generated ShapeNet-like objects."""
