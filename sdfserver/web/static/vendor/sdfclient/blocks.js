/** What a packed field block holds, taken apart (the Python client's `Block.distance` and `Block.colour`). */
/**
 * Distances in voxels. A distance block's own array (uint8, int16 or float32); a packed block's
 * magnitudes: the high byte (Uint8Array) of a Manhattan world's values, the square root
 * (Float32Array) of a Euclidean world's. The sign of a signed world's solids is not in a packed
 * block (read `format: "distance"`).
 */
export function distances(block) {
    if (block.format !== "packed")
        return block.data;
    const packed = block.data;
    if (block.content === "squared_distance")
        return Float32Array.from(packed, Math.sqrt);
    return Uint8Array.from(packed, (v) => v >> 8);
}
/** The low byte of a Manhattan world's packed field: each voxel's value, 0 in air. */
export function colours(block) {
    if (block.format !== "packed")
        throw new TypeError(`a ${block.format} block has no colour; read with format: "packed"`);
    if (block.content === "squared_distance") {
        throw new TypeError("a Euclidean world's packed field holds squared distances, no colour; read the voxels");
    }
    return Uint8Array.from(block.data, (v) => v & 0xff);
}
