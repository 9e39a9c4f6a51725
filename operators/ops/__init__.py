"""The operators, one module per concern, and the command line.

Modules
-------
common    what every operator shares: finding the setup, poll messages, reports
setup     Add / Remove FurCollide, Add / Remove Collider, Reset Cache
bake      Bake, Bake All, Free Bake, Free All Bakes (the modal driver of a bake)
sampler   Fur Sampler
attach    Fur Attach Bind / Unbind
groom     Bind Groom, Remove Groom Output
children  Make Children Output, Use Rest Position
pipeline  Collider Distance, Children from Guides, the Fur Pipeline panel's scene settings
scene     the scene settings FurCollide needs: Lock Interface, Play Every Frame
cli       ``blender -b --command furcollide bake`` (or ``free``, ``info``)
"""
