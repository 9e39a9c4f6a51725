"""What happens when Blender changes frame: the frame's path through the glue.

A frame reads top to bottom: ``handlers`` -> ``scenes`` -> ``rules`` (with ``inputs``
and ``record``) -> ``solve`` -> ``output`` -> ``groom`` -> ``children``.

Modules
-------
handlers    Blender's handlers: thin loops over the setups that never raise
scenes      a setup in the scenes its hair is in: solved in its own, shown in the others
rules       the frame rules: what a frame does (solve, show cached, hold, pass through)
setup       ``Setup``: one setup as one evaluation sees it
inputs      the evaluated source read into ``FrameInputs``; the motion before collision
record      the frame-inputs record of a cached frame, and what changed since
colliders   which objects collide; their core Colliders kept across frames
attach      Fur Attach: the binding's storage and the attached input curves
solve       ``solve_frame``: the one solve of playback, bake, the command line
output      writing the output hair: positions, handles, status, colours, attributes
groom       the render groom stage: the dense groom follows the guides, clearance pass
children    the children stage: the output's own children stack, cleared live
topology    a source whose curves change every frame: the message and the fix
clock       milliseconds per stage of the frame being evaluated
"""
