"""Datasets of point clouds in the layouts the completion literature ships (ShapeNet-55/34), and
the PCD reader and writer they need."""
