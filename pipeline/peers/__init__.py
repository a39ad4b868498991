"""The field's open trackers run on our plots, as peers of ours on the bench."""
