"""Upper-level policies π(ω|s), context features and Dynamic Movement Primitives."""
