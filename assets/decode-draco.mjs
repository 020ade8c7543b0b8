// Writes a copy of a Draco-compressed glTF binary (KHR_draco_mesh_compression) with plain
// accessors, which the renderer reads. Needs Node and, from npm, @gltf-transform/core@4,
// @gltf-transform/extensions@4 and draco3dgltf:
//   node decode-draco.mjs in.glb out.glb
import { NodeIO } from '@gltf-transform/core';
import { ALL_EXTENSIONS, KHRDracoMeshCompression } from '@gltf-transform/extensions';
import draco3d from 'draco3dgltf';

const [input, output] = process.argv.slice(2);
const io = new NodeIO()
  .registerExtensions(ALL_EXTENSIONS)
  .registerDependencies({ 'draco3d.decoder': await draco3d.createDecoderModule() });
const document = await io.read(input);
for (const extension of document.getRoot().listExtensionsUsed()) {
  if (extension.extensionName === KHRDracoMeshCompression.EXTENSION_NAME) extension.dispose();
}
await io.write(output, document);
