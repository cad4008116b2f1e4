"""robots/coco."""
