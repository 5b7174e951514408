// The phone page's camera mode: what the page does with camera.js's poses. Poses pass the same
// filter as AR mode's; the orientation sensors, where the phone has them, give the rotation
// (OrientationFusion); when the marker is lost the clutch lets go and the drag pads take over
// until it is found again.

import { CameraTracker } from "./camera.js";
import { quatMultiply } from "./devices.js";
import { DEVICE_FROM_BODY } from "./marker.js";
import { OrientationFusion, PhonePoseFilter } from "./pose_filter.js";
import { takePose } from "./tracked_pose.js";

const $ = (id) => document.getElementById(id);

const MARKER_LOST = "The camera lost the marker on your computer's screen, so the robot holds "
  + "still. Point the phone's back camera at the marker (25-60 cm away, the whole square in "
  + "view); until then the drag pads move the hand.";

// page: {phone, setClutch(engaged), banner(kind, text), showMode(text)}.
export async function startCameraMode(page) {
  const { phone, setClutch, banner, showMode } = page;
  const filter = new PhonePoseFilter();
  const fusion = new OrientationFusion();
  const tracker = new CameraTracker($("camera-view"), {
    pose: (pose, timeS) => {
      takePose(page, filter, pose, timeS, fusion.camera(pose.quaternion, timeS * 1000));
    },
    trackingLost: () => {
      phone.tracking = "lost";
      phone.source = "orientation";
      setClutch(false);
      showMode("camera: marker lost (drag pads)");
      banner("error", MARKER_LOST);
    },
    trackingBack: () => {
      const wasLost = phone.tracking === "lost";
      setClutch(false);  // the pads' position and the camera's differ: start a new stroke
      phone.tracking = "tracking";
      phone.source = "camera";
      filter.reset();
      showMode("6-DoF (camera + marker)");
      if (wasLost) banner("info", "Marker found: press the hold button to move.");
      else $("banner").className = "banner";
    },
    ended: (reason) => {
      setClutch(false);
      Object.assign(phone, { camera: null, filter: null, fusion: null, tracking: "none", source: "none" });
      document.body.classList.remove("camera");
      $("start-camera").hidden = false;
      showMode("orientation sensors + drag");
      if (reason !== "stopped") banner("error", "The camera stopped. Tap \"Track the marker\" to start it again, or use the drag pads.");
    },
  });
  phone.tracking = "starting";
  try {
    await tracker.start();
  } catch (error) {  // refused, no camera, or in use by another app
    phone.tracking = "none";
    banner("error", `The camera could not be started (${error.name === "NotAllowedError" ? "not allowed" : error.message}). The drag pads still work.`);
    return;
  }
  Object.assign(phone, { camera: tracker, filter, fusion });
  document.body.classList.add("camera");
  $("start-camera").hidden = true;
  showMode("camera: looking for the marker");
  banner("info", "Point the phone's back camera at the marker on your computer's screen.");
}

// A device-orientation reading while the camera runs: it steadies the rotation.
export function cameraOrientation(phone, deviceQuaternion) {
  if (phone.fusion) phone.fusion.sensor(quatMultiply(deviceQuaternion, DEVICE_FROM_BODY), performance.now());
}
