// The phone's WebXR tracking (Android Chrome with ARCore): an `immersive-ar` session whose
// viewer pose is the phone's 6-DoF pose. The page's controls stay usable in AR through the
// DOM overlay; where the overlay is missing, a tap on the screen (an XR select) is the clutch.

const TRACKING_LOST_AFTER_MS = 300;  // no pose, or only an emulated position, for this long

// WebXR is y-up with -z forward; the robot's frame is z-up with x forward.
export function xrToRobot({ position: p, orientation: q }) {
  return { position: [-p.z, -p.x, p.y], quaternion: [-q.z, -q.x, q.y, q.w] };
}

export async function arSupported() {
  if (!window.isSecureContext || !navigator.xr) return false;
  return navigator.xr.isSessionSupported("immersive-ar").catch(() => false);
}

// One AR session. handlers: pose({position, quaternion}, timeS), trackingLost(), trackingBack(),
// selectStart(), selectEnd(), reset() (the system re-centred its origin), ended(reason).
export class XrTracker {
  constructor(overlayRoot, handlers) {
    this.overlayRoot = overlayRoot;
    this.handlers = handlers;
    this.session = null;
    this.space = null;
    this.tracking = false;
    this.lostSinceMs = null;
    this.overlay = "none";  // the DOM overlay the browser gave: "screen", "floating", "none"
  }

  async start() {
    // beforexrselect on the controls: a tap on a button is that button, not also a select.
    for (const control of this.overlayRoot.querySelectorAll("button, [data-xr-control]")) {
      control.addEventListener("beforexrselect", (event) => event.preventDefault());
    }
    const session = await navigator.xr.requestSession("immersive-ar", {
      requiredFeatures: ["local"],
      optionalFeatures: ["dom-overlay"],
      domOverlay: { root: this.overlayRoot },
    });
    this.session = session;
    this.overlay = session.domOverlayState ? session.domOverlayState.type : "none";
    const gl = document.createElement("canvas").getContext("webgl", { xrCompatible: true });
    session.updateRenderState({ baseLayer: new XRWebGLLayer(session, gl) });
    this.space = await session.requestReferenceSpace("local");
    this.space.addEventListener("reset", () => this.handlers.reset());
    session.addEventListener("selectstart", () => this.handlers.selectStart());
    session.addEventListener("selectend", () => this.handlers.selectEnd());
    session.addEventListener("visibilitychange", () => {
      if (session.visibilityState !== "visible") this.#lost();  // e.g. a system dialog on top
    });
    session.addEventListener("end", () => {
      this.session = null;
      this.tracking = false;
      this.handlers.ended(document.visibilityState === "hidden" ? "hidden" : "ended");
    });
    session.requestAnimationFrame((t, frame) => this.#frame(t, frame));
  }

  async stop() {
    if (this.session) await this.session.end().catch(() => {});
  }

  #frame(timeMs, frame) {
    if (!this.session) return;
    this.session.requestAnimationFrame((t, f) => this.#frame(t, f));
    const pose = frame.getViewerPose(this.space);
    if (!pose || pose.emulatedPosition) {  // only orientation, or nothing: not 6-DoF now
      this.lostSinceMs ??= timeMs;
      if (timeMs - this.lostSinceMs >= TRACKING_LOST_AFTER_MS || !pose) this.#lost();
      return;
    }
    this.lostSinceMs = null;
    if (!this.tracking) {
      this.tracking = true;
      this.handlers.trackingBack();
    }
    this.handlers.pose(xrToRobot(pose.transform), timeMs / 1000);
  }

  #lost() {
    if (!this.tracking) return;
    this.tracking = false;
    this.handlers.trackingLost();
  }
}
