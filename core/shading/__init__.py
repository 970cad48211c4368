"""Shading nodes evaluated per shading point: the procedural textures (`procedural`)."""
