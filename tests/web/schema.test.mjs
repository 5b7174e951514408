// The page's JSON Schema validator (web/static/schema.js): each keyword on small schemas, then
// the real protocol schema, which must use no keyword the validator does not know.

import assert from "node:assert/strict";
import { describe, test } from "node:test";

import { compile, SchemaError } from "../../src/crowdteleop/web/static/schema.js";
import { realSchema } from "./python.mjs";

const accepts = (schema, value) => assert.deepEqual(compile(schema)(value), [], JSON.stringify(value));
const refuses = (schema, value, pattern) => {
  const problems = compile(schema)(value);
  assert.ok(problems.length > 0, `accepted ${JSON.stringify(value)}`);
  if (pattern) assert.match(problems.join("; "), pattern);
};

describe("types", () => {
  test("integer is a whole number, number any finite one", () => {
    accepts({ type: "integer" }, 3);
    accepts({ type: "integer" }, 3.0);
    refuses({ type: "integer" }, 3.5, /expected integer/);
    accepts({ type: "number" }, 3);
    accepts({ type: "number" }, -0.25);
  });
  test("NaN and infinities are no JSON numbers", () => {
    for (const value of [NaN, Infinity, -Infinity]) {
      refuses({ type: "number" }, value, /expected number/);
      refuses({ type: "integer" }, value);
    }
  });
  test("no coercion: '1' is no number, 1 no boolean, [] no object", () => {
    refuses({ type: "number" }, "1");
    refuses({ type: "boolean" }, 1);
    refuses({ type: "object" }, []);
    refuses({ type: "array" }, {});
    refuses({ type: "string" }, null);
    accepts({ type: ["string", "null"] }, null);
    accepts({ type: "null" }, null);
  });
});

test("const and enum", () => {
  accepts({ const: 1 }, 1);
  refuses({ const: 1 }, 2, /expected 1/);
  refuses({ const: "pose" }, "Pose");
  accepts({ enum: ["a", "b"] }, "b");
  refuses({ enum: ["a", "b"] }, "c", /one of/);
});

test("numeric bounds, inclusive and exclusive", () => {
  const schema = { type: "number", minimum: 0, maximum: 10 };
  accepts(schema, 0);
  accepts(schema, 10);
  refuses(schema, -0.001, /below/);
  refuses(schema, 10.5, /above/);
  const open = { type: "number", exclusiveMinimum: 0, exclusiveMaximum: 1 };
  accepts(open, 0.5);
  refuses(open, 0);
  refuses(open, 1);
});

test("string length counts code points; pattern", () => {
  accepts({ type: "string", maxLength: 2 }, "😀😀");
  refuses({ type: "string", maxLength: 1 }, "ab", /longer/);
  refuses({ type: "string", minLength: 1 }, "", /shorter/);
  accepts({ type: "string", pattern: "^[a-z]+$" }, "abc");
  refuses({ type: "string", pattern: "^[a-z]+$" }, "ab1", /does not match/);
});

describe("objects", () => {
  const schema = {
    type: "object", additionalProperties: false, required: ["a"],
    properties: { a: { type: "integer" }, b: { type: "string" } },
  };
  test("required, properties, additionalProperties false", () => {
    accepts(schema, { a: 1 });
    accepts(schema, { a: 1, b: "x" });
    refuses(schema, { b: "x" }, /missing field a/);
    refuses(schema, { a: 1, c: 2 }, /unexpected field c/);
    refuses(schema, { a: "1" }, /\/a: expected integer/);
  });
  test("an undefined field is absent, as JSON.stringify sends it", () => {
    refuses(schema, { a: undefined }, /missing field a/);
    accepts(schema, { a: 1, b: undefined });
  });
  test("additionalProperties as a schema", () => {
    const counts = { type: "object", additionalProperties: { type: "integer" } };
    accepts(counts, { x: 1, y: 2 });
    refuses(counts, { x: 1, y: "2" }, /\/y/);
  });
});

test("tuples (prefixItems) and lists (items)", () => {
  const triple = { type: "array", prefixItems: [{ type: "number" }, { type: "number" }, { type: "number" }],
                   minItems: 3, maxItems: 3 };
  accepts(triple, [0, 1.5, -2]);
  refuses(triple, [0, 1], /fewer than 3/);
  refuses(triple, [0, 1, 2, 3], /more than 3/);
  refuses(triple, [0, NaN, 2], /\/1: expected number/);
  const list = { type: "array", items: { type: "number", minimum: 0 }, maxItems: 2 };
  accepts(list, []);
  refuses(list, [1, -1], /\/1: -1 is below 0/);
});

describe("$ref, oneOf, anyOf, discriminator", () => {
  const union = {
    $defs: {
      A: { type: "object", properties: { type: { const: "a" }, x: { type: "integer" } },
           required: ["x"], additionalProperties: false },
      B: { type: "object", properties: { type: { const: "b" } }, additionalProperties: false },
    },
    oneOf: [{ $ref: "#/$defs/A" }, { $ref: "#/$defs/B" }],
  };
  test("oneOf: exactly one branch", () => {
    accepts(union, { type: "a", x: 1 });
    accepts(union, { type: "b" });
    refuses(union, { type: "a" }, /none of oneOf/);
    refuses({ oneOf: [{ type: "number" }, { type: "integer" }] }, 1, /2 of oneOf/);
  });
  test("a discriminator picks the branch by tag and names unknown tags", () => {
    const tagged = { ...union, discriminator: { propertyName: "type", mapping: { a: "#/$defs/A", b: "#/$defs/B" } } };
    accepts(tagged, { type: "a", x: 1 });
    refuses(tagged, { type: "a", x: 1.5 }, /^\/x: expected integer/);
    refuses(tagged, { type: "c" }, /\/type: unknown type "c"/);
    refuses(tagged, { x: 1 }, /unknown type undefined/);
  });
  test("anyOf (pydantic's nullable)", () => {
    const nullable = { anyOf: [{ enum: ["phone", "keyboard"], type: "string" }, { type: "null" }] };
    accepts(nullable, null);
    accepts(nullable, "phone");
    refuses(nullable, "toaster", /none of anyOf/);
  });
  test("boolean schemas", () => {
    accepts(true, 5);
    refuses(false, 5);
  });
});

test("the schema itself is checked when compiled", () => {
  assert.throws(() => compile({ type: "number", multipleOf: 2 }), SchemaError);
  assert.throws(() => compile({ properties: { a: { format: "uri" } } }), /unsupported keyword format/);
  assert.throws(() => compile({ $ref: "#/$defs/Missing" }), /does not resolve/);
  assert.throws(() => compile({ $ref: "https://example.com/s.json" }), /only local/);
  assert.throws(() => compile({ type: "float" }), /unknown type float/);
  assert.doesNotThrow(() => compile({ title: "T", description: "d", default: 1, type: "integer" }));
});

test("the real protocol schema uses only keywords the validator knows", () => {
  const schema = realSchema();
  assert.deepEqual(Object.keys(schema.channels).sort(), ["control", "events", "server"]);
  for (const channelSchema of Object.values(schema.channels)) assert.doesNotThrow(() => compile(channelSchema));
});
