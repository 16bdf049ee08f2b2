// openapi_validate.mjs — validates an OpenAPI document against the OpenAPI Initiative's own
// JSON Schemas with @seriousme/openapi-schema-validator (npm, web/package.json's tooling),
// so that tests/http_openapi.py has a real validator on Debian 12, which packages none:
//
//   node tests/openapi_validate.mjs server/openapi.json      # exit 0 valid, 1 not, 2 cannot run
import { readFile } from "node:fs/promises";
import { dirname, join } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
const file = process.argv[2];
if (!file) {
  console.error("usage: node tests/openapi_validate.mjs DOCUMENT.json");
  process.exit(2);
}
let Validator;
try {
  ({ Validator } = await import(
    pathToFileURL(join(root, "web", "node_modules", "@seriousme", "openapi-schema-validator", "index.js")).href
  ));
} catch (e) {
  console.error(`cannot load @seriousme/openapi-schema-validator (cd web && npm ci): ${e.message}`);
  process.exit(2);
}
const document = JSON.parse(await readFile(file, "utf8"));
const validator = new Validator();
const result = await validator.validate(document);
console.log(JSON.stringify({ valid: result.valid, version: validator.version, errors: result.errors ?? [] }));
process.exit(result.valid ? 0 : 1);
