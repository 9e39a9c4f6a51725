"""What happens when Blender changes frame: the frame's path through the glue.

A frame reads top to bottom (``spine``): ``handlers`` -> ``scenes`` -> ``spine``: read once
(``inputs``), what changed since (``rules``), decide (``rules``, with ``record``), solve
(``solve``, with ``colliders``), write once (``output``), the stages after (``groom``,
``children``), the status once (``output``).

Modules
-------
handlers    Blender's handlers: thin loops over the setups that never raise
scenes      a setup in the scenes its hair is in: solved in its own, shown in the others
spine       a frame top to bottom: read once, decide, solve, write once, the stages after
rules       the frame rules as a decision that writes nothing: what a frame shows and why
setup       ``Setup``: one setup as one evaluation sees it
inputs      the frame read once: the evaluated source into ``FrameInputs``, the settings
record      the frame-inputs record of a cached frame and what changed; what was seen last
colliders   which objects collide; their core Colliders kept across frames
attach      Fur Attach: the binding's storage and the attached input curves
solve       the solver and the state a frame starts from; ``solve_frame``: the one solve
output      the one write of the output hair and the one status of a frame
groom       the render groom stage: the dense groom follows the guides, clearance pass
children    the children stage: the output's own children stack, cleared live
topology    a source whose curves change every frame: the message and the fix
clock       milliseconds per stage of the frame being evaluated
"""
