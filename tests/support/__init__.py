"""Test scaffolding shared by the specs (not part of fw)."""
