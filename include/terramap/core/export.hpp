#pragma once
/// \file
/// Symbol visibility for everything that crosses a shared-library boundary.
///
/// Plugins are built with hidden visibility (terramap_add_plugin); the terramap libraries
/// export what carries TERRAMAP_API so every plugin resolves it to one definition.
/// TERRAMAP_LOCAL marks inline helpers that allocate memory the caller frees (for example
/// LayeredMap::toMatrix): they are compiled into, and bound within, each library or plugin
/// that calls them, so allocation and deallocation always use the same build's allocator
/// (Eigen's allocator depends on compile flags; see docs/plugins.md "Compile flags").

#define TERRAMAP_API __attribute__((visibility("default")))
#define TERRAMAP_LOCAL __attribute__((visibility("hidden")))
