"""The built-in node types of the M3C pipeline, in the thesis's order (importing this module registers them)."""
