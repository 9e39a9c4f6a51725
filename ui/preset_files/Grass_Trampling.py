import math

import bpy

fc = bpy.context.object.furcollide
settings = fc.source.furcollide if fc.is_output and fc.source else fc
furcollide_settings_version = 1

settings.mode = 'BEND'
settings.rotation_precision = math.radians(0.5)
settings.max_angle = math.radians(170.0)
settings.affected_connected_cvs = 2
settings.cv_falloff = 0.5
settings.attract_to_growth_surface = False
settings.follow_collider_motion = True
settings.collision_offset = 0.01
settings.shrink = False
settings.scale_minimum = 0.5
settings.scale_angle = math.radians(90.0)
settings.recovery_rate = 0.05
settings.plasticity = 0.6
settings.pinch_resolution = 'STOP'
settings.recover_pinched = True
