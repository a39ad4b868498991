"""The neural tracker: tracks and management, estimators, association gates, the tracking loop."""
