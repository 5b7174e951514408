"""The teleop server: one real-time simulated robot per worker, over WebRTC."""
