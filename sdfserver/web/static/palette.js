// The brush's colours come from the open world's palette: voxel value v (1..255) is drawn as
// palette[v - 1] (GET /v1/worlds/{id} gives it); a world without one is drawn in RGB332, the
// renderer's default (kernels/render.cl), so the picker shows exactly what a stroke will look like.

export function rgb332Palette() {
  const out = [];
  for (let v = 1; v < 256; v++) {
    out.push([Math.floor(((v >> 5) & 7) * 255 / 7), Math.floor(((v >> 2) & 7) * 255 / 7), (v & 3) * 85]);
  }
  return out;
}

export function worldPalette(world) {
  return Array.isArray(world?.palette) && world.palette.length === 255 ? world.palette : rgb332Palette();
}

export const rgbCss = ([r, g, b]) => `rgb(${r}, ${g}, ${b})`;
export const rgbHex = (rgb) => "#" + rgb.map((c) => c.toString(16).padStart(2, "0")).join("");

// The value whose palette colour is nearest `hex` ("#rrggbb"): a custom colour picks from the
// palette, since a voxel holds an index and not a colour.
export function nearestValue(palette, hex) {
  const v = parseInt(hex.slice(1), 16);
  const want = [(v >> 16) & 255, (v >> 8) & 255, v & 255];
  let best = 1, bestD = Infinity;
  palette.forEach((c, i) => {
    const d = (c[0] - want[0]) ** 2 + (c[1] - want[1]) ** 2 + (c[2] - want[2]) ** 2;
    if (d < bestD) { bestD = d; best = i + 1; }
  });
  return best;
}

// One button per value, button i for value i + 1; `onPick(value)` when one is clicked.
export function showSwatches(container, palette, selected, onPick) {
  container.replaceChildren(...palette.map((rgb, i) => {
    const button = document.createElement("button");
    button.type = "button";
    button.style.background = rgbCss(rgb);
    button.title = `${i + 1}: ${rgbHex(rgb)}`;
    button.dataset.value = String(i + 1);
    button.onclick = () => onPick(i + 1);
    return button;
  }));
  selectSwatch(container, selected);
}

export function selectSwatch(container, value) {
  for (const b of container.children) b.classList.toggle("selected", Number(b.dataset.value) === value);
}
