import math

import bpy

fc = bpy.context.object.furcollide
settings = fc.source.furcollide if fc.is_output and fc.source else fc
furcollide_settings_version = 1

settings.mode = 'STIFF'
settings.rotation_precision = math.radians(0.25)
settings.max_angle = math.radians(120.0)
settings.affected_connected_cvs = 2
settings.cv_falloff = 0.5
settings.attract_to_growth_surface = False
settings.follow_collider_motion = False
settings.collision_offset = 0.002
settings.shrink = True
settings.scale_minimum = 0.6
settings.scale_angle = math.radians(60.0)
settings.recovery_rate = 0.3
settings.plasticity = 0.0
settings.pinch_resolution = 'STOP'
settings.recover_pinched = True
