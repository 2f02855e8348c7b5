"""The pass library on Vulkan: the passes a schedule's tasks execute (:mod:`.recorders`), the same
passes on images of their own for measuring (:mod:`.standalone`), the particle update
(:mod:`.particle_update`), drawing helpers (:mod:`.draw`) and their GLSL sources (`shaders/`)."""
