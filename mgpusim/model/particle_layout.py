"""The particle demo's data layout and time step, shared by the schedule (memory footprints,
buffer sizes) and the Vulkan particle passes that fill those buffers.

Per particle: its state is 4 float4 (position, direction + velocity, spawn + size, life), the
update's calc buffer 2 float4 (position; alive, max life), the billboard 6 vertices x
(position, uv) = 12 float4.
"""
STATE_BYTES, CALC_BYTES, VERTEX_BYTES = 64, 32, 192

#: Seconds one particle update advances (one frame at 60 Hz); a "new wait" update that follows
#: skipped ones advances that many steps more.
UPDATE_DT = 1 / 60
