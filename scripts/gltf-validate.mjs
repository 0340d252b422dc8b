// Validates a glTF 2.0 file with the Khronos glTF validator (installed by scripts/setup.d/gltf.sh):
//   node scripts/gltf-validate.mjs FILE.glb
// Prints the validator's report as JSON; exit code 0 = no errors, 1 = errors, 2 = cannot run.
import { createRequire } from "node:module";
import { readFile } from "node:fs/promises";
import path from "node:path";
import { fileURLToPath } from "node:url";

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), "..");
const require = createRequire(path.join(root, ".tools/gltf-validator/node_modules/"));
const file = process.argv[2];
if (!file) {
  console.error("usage: node scripts/gltf-validate.mjs FILE.glb");
  process.exit(2);
}
let validator;
try {
  validator = require("gltf-validator");
} catch (e) {
  console.error(`gltf-validator is not installed: run bash scripts/setup.d/gltf.sh (${e.message})`);
  process.exit(2);
}
const data = new Uint8Array(await readFile(file));
const report = await validator.validateBytes(data, { uri: path.basename(file), maxIssues: 100 });
console.log(JSON.stringify(report, null, 1));
process.exit(report.issues.numErrors > 0 ? 1 : 0);
