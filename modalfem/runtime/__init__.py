"""Real-time modal runtime (numpy only): exact per-mode integration, rigid body, impulses, contact, sound."""
