"""Views of recordings: figures and the Markdown report, the Foxglove JSON view."""
