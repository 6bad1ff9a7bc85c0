"""PixelMuJoCo: MJX physics for Ant, HalfCheetah, Hopper and Swimmer (Gymnasium v5 semantics,
`MuJoCo/*-v0`), seen through a pure-JAX ray caster (`PixelMuJoCo/*-v0`).

- `models`, `base`, `ant`, `half_cheetah`, `hopper`, `swimmer`: the physics envs (state observations).
- `render`, `camera`, `floor`: the jitted, vmappable renderer, MuJoCo's tracking camera, floor textures.
- `pixel`: the pixel/noise/state observation layer with frame skip and frame stack.
- `stack`: the frame stack's layouts (grayscale x 4 packed into one uint32 per pixel).
"""
