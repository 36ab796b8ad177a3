"""What the offline backend calls itself in its replies and in every log and report that names it:
one label, so that it reads the same wherever a user meets it."""

BACKEND = "offline rule-based backend"
