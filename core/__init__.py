"""The shared layer below bookings: accounts, audit, errors, API conventions, OpenAPI helpers,
robot-independent health checks and the live bus. It imports nothing above it."""
