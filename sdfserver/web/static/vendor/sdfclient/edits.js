/**
 * Edit operations in their wire form.
 *
 *     await client.edit(id, [sphere([32, 32, 32], 6, 0xe0), box([0, 0, 0], [64, 4, 64], 0x1c),
 *                            voxels(new Uint16Array([1, 2, 3, 255])), eraseSphere([32, 32, 32], 3)]);
 *
 * Colour 0 erases. Boxes are half-open (`min <= p < max`); a voxel `p` is in a sphere when
 * `|p - center| <= radius`. Explicit voxels travel as one uint16 N x 4 blob (x, y, z, colour).
 */
import { blob } from "./wire.js";
export function sphere(center, radius, colour = 255) {
    return { op: "sphere", center: [...center], radius, colour };
}
export function box(min, max, colour = 255) {
    return { op: "box", min: [...min], max: [...max], colour };
}
export function eraseSphere(center, radius) {
    return sphere(center, radius, 0);
}
export function eraseBox(min, max) {
    return box(min, max, 0);
}
/** Explicit voxels: a Uint16Array of x, y, z, colour quadruples (sent as it is), or numbers as a
 * flat list or rows of four (checked, then sent as uint16). */
export function voxels(quads) {
    let flat;
    if (quads instanceof Uint16Array) {
        flat = quads;
    }
    else {
        const list = quads;
        const values = list.length > 0 && Array.isArray(list[0]) ? quads.flat() : Array.from(quads);
        if (values.some((v) => !Number.isInteger(v) || v < 0 || v > 0xffff)) {
            throw new RangeError("voxel coordinates and colours must be integers that fit in uint16");
        }
        flat = Uint16Array.from(values);
    }
    if (flat.length % 4 !== 0)
        throw new RangeError(`voxels are x, y, z, colour quadruples; got ${flat.length} numbers`);
    return { op: "voxels", voxels: blob(flat, [flat.length / 4, 4]) };
}
