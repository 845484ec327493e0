// Validate glTF files with the Khronos glTF-Validator (npm gltf-validator, a devDependency):
// node tests/js/validate_gltf.cjs FILE... prints one JSON report per file, one per line.
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

(async () => {
  for (const file of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: path.basename(file),
      maxIssues: 0,
      externalResourceFunction: () => Promise.reject(new Error('no external resources expected')),
    });
    console.log(JSON.stringify(report));
  }
})().catch((e) => { console.error(String(e)); process.exit(1); });
