"""Shading nodes: the compiled functions a material's node program evaluates per shading point.

`color`: the colour and converter nodes (Mix in Color mode, Color Ramp, the curve nodes, Hue/Saturation/Value,
Invert, Bright/Contrast, Gamma, RGB to BW, Separate/Combine Color, Blackbody, Wavelength).
"""
