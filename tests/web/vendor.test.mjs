// The vendored libraries (web/static/vendor/) are the files their registry published, byte for
// byte: a copy edited or split in place no longer is the version its folder is named after.

import assert from "node:assert/strict";
import { createHash } from "node:crypto";
import { readFileSync, readdirSync } from "node:fs";
import { test } from "node:test";

const VENDOR = new URL("../../src/crowdteleop/web/static/vendor/", import.meta.url);

// sha256 of each file as published: `npm pack js-aruco2@2.0.0`, package/src/ and package/.
const PUBLISHED = {
  "js-aruco2-2.0.0/cv.js": "1cb9e470388b32fbd132dc74d16ade42703126b805b044985418039b9ea8182b",
  "js-aruco2-2.0.0/aruco.js": "5fbd6344b8152de381cbe2ff64aa9c285999f15e8492cb092027542fe11d7d54",
  "js-aruco2-2.0.0/LICENSE.txt": "1a304e21bce4169c8bd6dac5aa8aae843bbb9d8a5193fbe50ab8d64242a0d76c",
  // `npm pack uplot@1.6.32`: package/dist/uPlot.esm.js, package/dist/uPlot.min.css, package/LICENSE.
  "uplot-1.6.32/uPlot.esm.js": "5dd9b3281aa64b461b42d9945f6adb2649d346502b12281a9ae0d46599a80eba",
  "uplot-1.6.32/uPlot.min.css": "df630c6a8d6f8eeaff264b50f73ce5b114f646ffd9a0bb74f049b0a00135fa04",
  "uplot-1.6.32/LICENSE": "8f989229699b4fe2f1a0432d0e9edc338a8a911e250e2d1b01ecd770a5f5b1bd",
};

const sha256 = (path) => createHash("sha256").update(readFileSync(new URL(path, VENDOR))).digest("hex");

test("every vendored file is one the registry published, unchanged", () => {
  const files = readdirSync(VENDOR, { recursive: true, withFileTypes: true })
    .filter((entry) => entry.isFile())
    .map((entry) => `${entry.parentPath ?? entry.path}/${entry.name}`.slice(VENDOR.pathname.length));
  assert.deepEqual(files.sort(), Object.keys(PUBLISHED).sort());
  for (const [path, digest] of Object.entries(PUBLISHED)) {
    assert.equal(sha256(path), digest, path);
  }
});
