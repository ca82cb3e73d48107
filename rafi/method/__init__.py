"""The paper's method, one module per step (named like its workflow rule where there is one):
``clean``, ``runs``, ``equilibrium``, ``rank``, ``fit`` (one OLS per training speed),
``fuzzy`` (triangular blending), ``model`` (the RAFI model artefact), ``validate``; ``paper``
holds the paper's published numbers.
"""
