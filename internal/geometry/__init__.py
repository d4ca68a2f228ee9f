"""Geometry out of a trained field: meshes by marching cubes, point clouds where views agree, PLY files, and their
scores against the generated scene's exact surfaces (tools.mesh, tools.points)."""
