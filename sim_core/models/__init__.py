"""The mass-spring physics: materials, laws, the force terms, the model builder and its sparse
pattern, stacks of N worlds, the validated range, organ phantoms."""
