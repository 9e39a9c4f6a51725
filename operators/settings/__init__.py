"""The setup's settings: Blender properties on the hair object, and reading them.

Modules
-------
properties           the settings on the source hair (``Object.furcollide``)
properties_pipeline  the fur pipeline stages' settings (motion, render groom, children)
property_helpers     the settings' update callbacks and property factories
angles               the angle settings: Blender angles over a store in degrees
core_values          the settings as the core takes them (degrees, lower-case choices)
versioning           files of earlier versions: their angle keys and drivers converted
fingerprints         core Settings from the properties; signature, structure, time key
keyed                keyed and driven settings: their values at any frame
maps                 parameter maps: per-curve settings read from the evaluated hair
motion               wind, jiggle, Region of Influence, distance: the core's plain values
"""
