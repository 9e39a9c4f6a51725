import bpy
fc = bpy.context.object.furcollide
settings = fc.source.furcollide if fc.is_output and fc.source else fc

settings.mode = 'stiff'
settings.rotation_precision = 0.30000001192092896
settings.max_angle = 150.0
settings.affected_connected_cvs = 2
settings.cv_falloff = 0.5
settings.attract_to_growth_surface = False
settings.follow_collider_motion = False
settings.shrink = True
settings.scale_minimum = 0.5
settings.scale_angle = 45.5
settings.recovery_rate = 0.25
settings.plasticity = 0.0
settings.pinch_resolution = 'growth_surface'
settings.recover_pinched = True
settings.collision_offset = 0.0
