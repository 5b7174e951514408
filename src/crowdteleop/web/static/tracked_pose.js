// What the phone page does with each pose AR or camera tracking gives: keep it raw (for tests
// and the re-centre), filter it (pose_filter.js), and end the stroke on a tracking glitch.

const GLITCH = "Tracking jumped, so the robot stopped. Press the hold button again.";

// page: {phone, setClutch, banner}; pose: {position, quaternion}; rotation: the orientation to
// filter, when something steadier than the pose's own is at hand (camera mode's sensors).
export function takePose(page, filter, pose, timeS, rotation = pose.quaternion) {
  const { phone } = page;
  phone.rawPose = { position: pose.position, quaternion: pose.quaternion };
  const out = filter.update(pose.position, rotation, timeS);
  if (out.glitch) {
    page.setClutch(false);
    page.banner("error", GLITCH);
    return;
  }
  phone.position = out.position;
  phone.quaternion = out.quaternion;
}
