"""Studies built on the physics of ``sim_core``: validation experiments (``experiments``), the
choice of a scene's mesh resolution and env stepping (``resolution``, ``stepping`` and the scenes
they solve), step-speed measurements (``bench``), the validation table (``demo``), the released cantilever
of the damping law (``damping``) and the ``tissue-sim`` command (``cli``).

The physics modules never import this package: it sits above them.
"""
