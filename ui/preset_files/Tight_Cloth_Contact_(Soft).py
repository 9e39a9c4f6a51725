import bpy

fc = bpy.context.object.furcollide
settings = fc.source.furcollide if fc.is_output and fc.source else fc

settings.mode = 'soft'
settings.rotation_precision = 0.25
settings.max_angle = 90.0
settings.affected_connected_cvs = 3
settings.cv_falloff = 0.5
settings.attract_to_growth_surface = False
settings.follow_collider_motion = False
settings.collision_offset = 0.001
settings.shrink = False
settings.scale_minimum = 0.5
settings.scale_angle = 90.0
settings.recovery_rate = 0.5
settings.plasticity = 0.0
settings.pinch_resolution = 'stop'
settings.recover_pinched = True
