"""The renderer core: NumPy arrays in, NumPy arrays out. Never imports bpy."""
