"""The browser navigation view (trame-slicer): a second shell over the navigation controller."""
