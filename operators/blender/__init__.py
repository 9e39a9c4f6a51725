"""Blender I/O that every room uses.

Modules
-------
bridge        numpy <-> bpy transfers (``foreach_get`` / ``foreach_set``, sizes checked)
compat        every difference between the supported Blender versions
dependencies  the outputs' *FurCollide Inputs* modifier (inputs evaluated in renders)
"""
