/**
 * What the client sends and returns. Positions and sizes are `[x, y, z]`; arrays are flat typed
 * arrays in the server's layout, C-ordered `(z, y, x)`, with their `shape` beside them.
 */
export {};
