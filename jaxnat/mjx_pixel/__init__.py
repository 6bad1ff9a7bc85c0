"""PixelMuJoCo: MJX physics rendered by a pure-JAX ray caster (not yet implemented)."""
