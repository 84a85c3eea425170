"""Parametric models of the mobile node's enclosures and antenna supports (CadQuery).

One module per model; ``python -m cad build`` writes STEP, STL and SVG files. See README.md.
"""
