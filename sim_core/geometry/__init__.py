"""Meshes: hexahedral and tetrahedral meshes, the reference hexahedron, meshing of closed surfaces."""
