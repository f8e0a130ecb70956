// A world, a sphere, its field read back, the three queries and the stream, then cleaned up.
// Run: node build/examples/quickstart.js [server URL]
import { Client, NotFound, box, sphere } from "sdfclient";

const client = new Client(process.argv[2] ?? "http://127.0.0.1:8000", { apiKey: process.env.SDFSERVER_API_KEY });
const world = await client.createWorld([32, 32, 32], { maxDistance: 16 });
try {
  const version = await client.edit(world.id, [box([0, 0, 0], [32, 1, 32], 0x1c), sphere([16, 8, 16], 4, 0xe0)]);
  const field = await client.readField(world.id, { minVersion: version }); // reads its own write
  const at = (x: number, y: number, z: number) => field.data[(z * 32 + y) * 32 + x];
  console.log(`field ${field.shape.join("x")} ${field.dtype}, version ${field.version}`);
  console.log(`distance above the sphere (16, 16, 16): ${at(16, 16, 16)}`);

  const points = await client.query(world.id, [[4.5, 3.5, 4.5]]);
  const spheres = await client.querySpheres(world.id, [[4.5, 3.5, 4.5, 1]]);
  const rays = await client.queryRays(world.id, [[16.5, 30.5, 16.5, 0, -1, 0, 100]]);
  console.log(`point: distance ${points.distances[0]}, sphere clearance ${spheres.clearances[0]}`);
  console.log(`ray down: hit ${rays.hits[0] === 1} at ${rays.distances[0]}, voxel ${Array.from(rays.voxels)}`);

  const stream = await client.stream(world.id);
  await stream.subscribe([[0, 0, 0], [32, 32, 32]]);
  const next = await stream.edit([sphere([4, 4, 4], 2, 0x03)]);
  for await (const message of stream) {
    if (message.type === "chunks" && message.version! >= next) {
      console.log(`version ${message.version}: ${message.chunks.length} chunks, first at ${message.chunks[0].origin}`);
      break;
    }
  }
  await stream.close();
} finally {
  await client.deleteWorld(world.id);
}
await client.getWorld(world.id).catch((error) => console.log(`deleted: ${error instanceof NotFound}`));
