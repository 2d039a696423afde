"""4D rigid-body physics: exact mass properties from simplices, contacts between convex polytopes, an
impulse solver with restitution and Coulomb friction, and a fixed-step world whose step is a pure
function of state and inputs (docs/physics.md)."""
