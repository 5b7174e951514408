// A JSON Schema (2020-12) validator for exactly the keywords pydantic emits for our protocol
// (crowdteleop/teleop/protocol.py, served at /protocol.json). The schema comes from our own
// server, so a keyword this file does not know means the Python side changed in a way the page
// cannot check: `compile` refuses it loudly instead of silently accepting everything.
// Written here rather than vendored: @cfworker/json-schema is eight modules and lets NaN pass
// as a number, and NaN must never reach the wire (JSON.stringify turns it into null).

const ANNOTATIONS = new Set(["$schema", "$id", "$comment", "title", "description", "default",
                             "examples", "deprecated", "readOnly", "writeOnly"]);
const SUBSCHEMA_LISTS = ["oneOf", "anyOf", "allOf", "prefixItems"];
const SUBSCHEMA_MAPS = ["$defs", "properties"];
const VALIDATION = new Set([...SUBSCHEMA_LISTS, ...SUBSCHEMA_MAPS, "$ref", "discriminator", "type",
  "const", "enum", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "minLength",
  "maxLength", "pattern", "required", "additionalProperties", "items", "minItems", "maxItems"]);
const TYPES = new Set(["null", "boolean", "object", "array", "number", "integer", "string"]);

export class SchemaError extends Error {}  // the schema itself is unusable (not the message)

// The JSON type of a value; NaN and infinities have none (they are not JSON numbers).
export function jsonType(value) {
  if (value === null) return "null";
  if (Array.isArray(value)) return "array";
  if (typeof value === "number") {
    if (!Number.isFinite(value)) return String(value);
    return Number.isInteger(value) ? "integer" : "number";
  }
  return typeof value;  // string, boolean, object; undefined, function, bigint are no JSON
}

function hasType(value, type) {
  const actual = jsonType(value);
  return actual === type || (type === "number" && actual === "integer");
}

function equal(a, b) {
  if (a === b) return true;
  if (jsonType(a) !== jsonType(b) || typeof a !== "object" || a === null) return false;
  const keysA = Object.keys(a), keysB = Object.keys(b);
  return keysA.length === keysB.length && keysA.every((key) => Object.hasOwn(b, key) && equal(a[key], b[key]));
}

function show(value) {
  if (typeof value === "number" && !Number.isFinite(value)) return String(value);
  if (value === undefined) return "undefined";
  const text = JSON.stringify(value);
  return text.length > 40 ? `${text.slice(0, 37)}...` : text;
}

// JSON.stringify drops undefined fields, so on the wire they are absent.
const present = (object, key) => Object.hasOwn(object, key) && object[key] !== undefined;

function resolve(root, ref) {
  if (!ref.startsWith("#")) throw new SchemaError(`only local $ref are supported, not ${ref}`);
  let node = root;
  for (const raw of ref.slice(1).split("/").slice(1)) {
    const key = decodeURIComponent(raw).replaceAll("~1", "/").replaceAll("~0", "~");
    if (node === null || typeof node !== "object" || !Object.hasOwn(node, key)) {
      throw new SchemaError(`$ref ${ref} does not resolve`);
    }
    node = node[key];
  }
  return node;
}

// Walk the whole schema once: unknown keywords, bad types and dangling $refs fail here.
function check(root, schema, where) {
  if (typeof schema === "boolean") return;
  if (jsonType(schema) !== "object") throw new SchemaError(`${where}: a schema must be an object`);
  for (const [keyword, value] of Object.entries(schema)) {
    if (ANNOTATIONS.has(keyword)) continue;
    if (!VALIDATION.has(keyword)) throw new SchemaError(`${where}: unsupported keyword ${keyword}`);
    if (SUBSCHEMA_LISTS.includes(keyword)) value.forEach((sub, i) => check(root, sub, `${where}/${keyword}/${i}`));
    if (SUBSCHEMA_MAPS.includes(keyword)) {
      for (const [name, sub] of Object.entries(value)) check(root, sub, `${where}/${keyword}/${name}`);
    }
    if (keyword === "items" || (keyword === "additionalProperties" && typeof value !== "boolean")) {
      check(root, value, `${where}/${keyword}`);
    }
    if (keyword === "$ref") resolve(root, value);
    if (keyword === "pattern") new RegExp(value, "u");  // throws on a pattern JS cannot read
    if (keyword === "type") {
      for (const type of [value].flat()) {
        if (!TYPES.has(type)) throw new SchemaError(`${where}: unknown type ${type}`);
      }
    }
    if (keyword === "discriminator") {
      for (const ref of Object.values(value.mapping || {})) resolve(root, ref);
    }
  }
}

function validate(root, schema, value, path, errors) {
  const fail = (message) => errors.push(`${path || "/"}: ${message}`);
  if (schema === true) return;
  if (schema === false) { fail("no value is allowed here"); return; }
  if (schema.$ref !== undefined) validate(root, resolve(root, schema.$ref), value, path, errors);
  if (schema.type !== undefined) {
    const types = [schema.type].flat();
    if (!types.some((type) => hasType(value, type))) {
      fail(`expected ${types.join(" or ")}, got ${jsonType(value)} ${show(value)}`);
      return;  // the other keywords would only repeat the same complaint
    }
  }
  if (schema.const !== undefined && !equal(value, schema.const)) {
    fail(`expected ${show(schema.const)}, got ${show(value)}`);
  }
  if (schema.enum !== undefined && !schema.enum.some((option) => equal(value, option))) {
    fail(`expected one of ${schema.enum.map(show).join(", ")}, got ${show(value)}`);
  }
  const type = jsonType(value);
  if (type === "number" || type === "integer") validateNumber(schema, value, fail);
  if (type === "string") validateString(schema, value, fail);
  if (type === "array") validateArray(root, schema, value, path, errors, fail);
  if (type === "object") validateObject(root, schema, value, path, errors, fail);
  validateCombinations(root, schema, value, path, errors, fail);
}

function validateNumber(schema, value, fail) {
  if (schema.minimum !== undefined && value < schema.minimum) fail(`${value} is below ${schema.minimum}`);
  if (schema.maximum !== undefined && value > schema.maximum) fail(`${value} is above ${schema.maximum}`);
  if (schema.exclusiveMinimum !== undefined && value <= schema.exclusiveMinimum) {
    fail(`${value} is not above ${schema.exclusiveMinimum}`);
  }
  if (schema.exclusiveMaximum !== undefined && value >= schema.exclusiveMaximum) {
    fail(`${value} is not below ${schema.exclusiveMaximum}`);
  }
}

function validateString(schema, value, fail) {
  const length = [...value].length;  // code points, as JSON Schema counts them
  if (schema.minLength !== undefined && length < schema.minLength) fail(`shorter than ${schema.minLength}`);
  if (schema.maxLength !== undefined && length > schema.maxLength) fail(`longer than ${schema.maxLength}`);
  if (schema.pattern !== undefined && !new RegExp(schema.pattern, "u").test(value)) {
    fail(`does not match ${schema.pattern}`);
  }
}

function validateArray(root, schema, value, path, errors, fail) {
  if (schema.minItems !== undefined && value.length < schema.minItems) fail(`fewer than ${schema.minItems} items`);
  if (schema.maxItems !== undefined && value.length > schema.maxItems) fail(`more than ${schema.maxItems} items`);
  const prefix = schema.prefixItems || [];
  value.forEach((item, i) => {
    const itemSchema = i < prefix.length ? prefix[i] : schema.items;
    if (itemSchema !== undefined) validate(root, itemSchema, item, `${path}/${i}`, errors);
  });
}

function validateObject(root, schema, value, path, errors, fail) {
  for (const key of schema.required || []) {
    if (!present(value, key)) fail(`missing field ${key}`);
  }
  const properties = schema.properties || {};
  for (const [key, item] of Object.entries(value)) {
    if (item === undefined) continue;
    if (Object.hasOwn(properties, key)) validate(root, properties[key], item, `${path}/${key}`, errors);
    else if (schema.additionalProperties === false) fail(`unexpected field ${key}`);
    else if (schema.additionalProperties !== undefined) {
      validate(root, schema.additionalProperties, item, `${path}/${key}`, errors);
    }
  }
}

function validateCombinations(root, schema, value, path, errors, fail) {
  const attempt = (sub) => { const found = []; validate(root, sub, value, path, found); return found; };
  for (const sub of schema.allOf || []) validate(root, sub, value, path, errors);
  // A discriminated union picks its branch by the tag, so errors name the real problem rather
  // than listing why the message is none of the eleven other types.
  const tagged = schema.discriminator && schema.discriminator.mapping && jsonType(value) === "object";
  if (tagged) {
    const { propertyName, mapping } = schema.discriminator;
    const tag = value[propertyName];
    if (typeof tag !== "string" || !Object.hasOwn(mapping, tag)) {
      errors.push(`${path}/${propertyName}: unknown ${propertyName} ${show(tag)}`);
    } else {
      validate(root, resolve(root, mapping[tag]), value, path, errors);
    }
  }
  if (schema.oneOf && !tagged) {
    const outcomes = schema.oneOf.map(attempt);
    const matches = outcomes.filter((found) => found.length === 0).length;
    if (matches === 0) fail(`matches none of oneOf (${outcomes.map((found) => found[0]).join("; ")})`);
    if (matches > 1) fail(`matches ${matches} of oneOf, not exactly one`);
  }
  if (schema.anyOf && !tagged) {
    const outcomes = schema.anyOf.map(attempt);
    if (!outcomes.some((found) => found.length === 0)) {
      fail(`matches none of anyOf (${outcomes.map((found) => found[0]).join("; ")})`);
    }
  }
}

// A validator for `schema`: value => list of problems ("/path: what is wrong"), empty if valid.
export function compile(schema) {
  check(schema, schema, "#");
  return (value) => {
    const errors = [];
    validate(schema, schema, value, "", errors);
    return errors;
  };
}
