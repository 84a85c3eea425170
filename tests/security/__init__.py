"""Every door of the portal and the agent tried as an attacker would (docs/security.md)."""
